"""``cell up``: the whole cell in the foreground, for interactive use (``cell home``, ``cell
move``, ``cell watch`` in another terminal).

It starts, from the shipped ``config/cell.yaml`` (or ``--params-file``), the processes ``make
run`` starts: the recorder (unless ``--no-record``) and :data:`~positioning_cell.names.CELL_NODES`,
plus the live view and the calibrator on request: the set ``launch/cell.launch.py`` starts on a
ROS install (:data:`~positioning_cell.names.OPTIONAL_NODES`). Each process logs to
``runs/<UTC timestamp>/logs/<executable>.log``; the bag goes to ``runs/<UTC timestamp>/bag``.
It prints both, says when every node is in the ROS graph, and then waits. Ctrl-C (SIGINT,
SIGTERM or SIGHUP) stops every node with SIGINT: the positioner stops the drives, the recorder
closes its bag. Exit 0 when every node stopped cleanly (1 when one did not); a node that
exits by itself (or does not come up within ``--timeout``) stops the others: exit 5
(``not_there``), naming it.
The cell runs on ``--domain`` (default ROS_DOMAIN_ID, else 0), on the loopback as any of the
cell's processes (:func:`positioning_cell.ros.processes.cell_environment`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file
from positioning_cell.errors import PositioningError
from positioning_cell.names import CellNode
from positioning_cell.polling import wait_until
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.tools.exits import Exit
from positioning_cell.tools.interruption import Interrupted, interruptible

#: How long the nodes may take to show in the graph when --timeout is not given, s.
UP_TIMEOUT = 60.0
#: Lines of a node's log shown when it exits by itself.
LOG_TAIL = 15


def chosen_nodes(switches: dict[str, bool]) -> list[CellNode]:
    """The nodes to start, in start order: the optional ones switched on (``switches``: switch
    name -> on; a switch not given takes its default) around the cell's own, as ``make run``
    and the launch file order them (the recorder first, to miss nothing)."""
    on = {node: switches.get(switch, default) for node, switch, default in names.OPTIONAL_NODES}
    return ([n for n in on if on[n] and n == names.RECORDER] + list(names.CELL_NODES)
            + [n for n in on if on[n] and n != names.RECORDER])


def domain_of(given: int | None) -> int:
    """The ROS domain: ``given``, else ROS_DOMAIN_ID, else 0. ValueError for a variable that
    is not a domain id."""
    if given is not None:
        return given
    text = os.environ.get('ROS_DOMAIN_ID', '').strip() or '0'
    if not text.isdigit() or not 0 <= int(text) <= 232:
        raise ValueError(f'ROS_DOMAIN_ID={text!r} is not a domain id 0..232')
    return int(text)


def _say(text: str) -> None:
    print(text, flush=True)  # a log read as it comes, also through a pipe or a file


def up(args: argparse.Namespace, say: Callable[[str], None] = _say,
       runs_dir: Path = Path('runs')) -> int:
    """``cell up`` (module docstring) with the parsed ``args``; the exit status."""
    if args.json:
        say('cell up: error: --json is not an option of up: it prints a log for people')
        return Exit.USAGE
    config = Path(args.params_file) if args.params_file else config_path('cell.yaml')
    try:
        load_parameter_file(config)
        domain = domain_of(args.domain)
    except (PositioningError, ValueError) as err:
        say(f'cell up: error: {err}')
        return Exit.USAGE
    nodes = chosen_nodes({'record': args.record, 'live_view': args.live_view,
                          'calibrator': args.calibrator})
    from positioning_cell.recording.description import write_description_file
    from positioning_cell.ros.cell_start import new_run_folder, run_overrides

    run_dir = new_run_folder(runs_dir)
    logs = run_dir / 'logs'
    env = cell_environment(domain)
    env.setdefault('ROS_LOG_DIR', str(logs / 'ros'))
    overrides = run_overrides(run_dir, write_description_file(run_dir, 'interactive', [config],
                                                              command=sys.argv))
    status: int = Exit.OK
    stopped_by = ''
    with interruptible() as signals:
        procs = Processes(env, logs)
        try:
            status = _serve(procs, nodes, config, overrides, domain, run_dir,
                            args.timeout or UP_TIMEOUT, say)
        except Interrupted as err:
            stopped_by = str(err)
        finally:
            with signals.ignored():  # stopping is not interrupted (a second Ctrl-C neither)
                if stopped_by:
                    say(f'cell up: {stopped_by}: stopping the cell')
                codes = procs.stop()
    say('cell up: stopped: ' + ', '.join(f'{k} (exit {v})' for k, v in codes.items()))
    if status == Exit.OK and any(code != 0 for code in codes.values()):
        say('cell up: not every node stopped cleanly (see the logs)')
        status = Exit.NOT_ACHIEVED
    return status


def _serve(procs: Processes, nodes: list[CellNode], config: Path, overrides: Path,
           domain: int, run_dir: Path, timeout: float, say: Callable[[str], None]) -> int:
    """Start ``nodes``, wait until the graph shows them, then until one exits (a signal
    raises Interrupted in between)."""
    for node in nodes:
        procs.start(node.executable, params=[config, overrides])
    say(f'cell up: ROS_DOMAIN_ID {domain}, parameters {config}')
    say(f'cell up: started {", ".join(n.executable for n in nodes)}')
    say(f'cell up: logs in {procs.log_dir}/<executable>.log'
        + (f'; bag {run_dir / "bag"}' if names.RECORDER in nodes else '; not recording'))
    from positioning_cell.ros.early import start_node

    client = start_node(domain, prefix='cell_up')
    try:
        def seen() -> bool | None:
            if procs.dead():
                return True  # said below
            shown = {name for name, _ in client.get_node_names_and_namespaces()}
            return {n.name for n in nodes} <= shown or None
        try:
            wait_until(seen, timeout, 'every node in the ROS graph')
        except TimeoutError:
            missing = sorted({n.name for n in nodes}
                             - {name for name, _ in client.get_node_names_and_namespaces()})
            say(f'cell up: error: not in the ROS graph after {timeout:g} s: '
                f'{", ".join(missing)} (see the logs)')
            return Exit.NOT_THERE
    finally:
        client.context.try_shutdown()
    if not procs.dead():
        say('cell up: ready. In another terminal: cell home, then cell move / status / watch '
            f'(ROS_DOMAIN_ID={domain}). Ctrl-C here stops the cell.')
        # Until a child exits (not reaped here: Processes reads its exit code); a signal
        # raises Interrupted meanwhile.
        os.waitid(os.P_ALL, 0, os.WEXITED | os.WNOWAIT)
    dead = procs.dead()
    for label in dead:
        tail = procs.log(label).rstrip().splitlines()[-LOG_TAIL:]
        say(f'cell up: {label} exited by itself (exit {procs.procs[label].returncode}); '
            'the end of its log:\n  ' + '\n  '.join(tail))
    say(f'cell up: error: {", ".join(dead)} exited: stopping the cell')
    return Exit.NOT_THERE
