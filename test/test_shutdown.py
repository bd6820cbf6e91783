"""Every node executable stops cleanly on SIGINT and on SIGTERM (and, running, on SIGHUP: its
terminal closed): exit 0, no traceback, no C++ "terminate called", within a bounded time,
wherever in its start the signal lands: while its modules load, while rclpy comes up and the
node is built, and once it runs (the recorder then leaves a closed bag).

Multi-process tier. The six executables run together in one private domain per trial. The
running case waits for a condition before it signals (every node answering its parameter
service); the sweep stops each node 10 times at moments spread over its start (the moment is
the variable of that test, not a wait for something). benchmarks/shutdown.py prints the stop
times against a bare rclpy node.
"""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
from cell_harness import Client, isolated_domain

from positioning_cell import names
from positioning_cell.ros.processes import cell_environment
from positioning_cell.testing.stops import Stop, stop_after, stop_commands

#: Every node started and signalled.
pytestmark = pytest.mark.nodes

#: A clean stop takes well under this on a loaded 2-core machine (the recorder drains its
#: queue, the player closes its bag).
STOP_BOUND_S = 15.0
#: The sweep: 10 stops per node, this far apart in the start (0 to 1.35 s after the entry
#: point runs; the nodes answer 0.41-0.57 s after their start (benchmarks/startup.py medians,
#: issue 24) and later under the parallel tier's load, so the first stops hit loading
#: processes and the last running nodes; benchmarks/shutdown.py takes 30).
STOPS, STEP_S = 10, 0.15


NODE_NAMES = {node.executable: node.name for node in names.NODE_EXECUTABLES}


def _unclean(stops: list[Stop]) -> list[Stop]:
    return [s for s in stops if not s.clean or s.seconds > STOP_BOUND_S]


def _described(stops: list[Stop]) -> str:
    """The stops that went wrong, each with its native stacks when they were written."""
    return '\n'.join(s.describe() for s in stops)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP],
                         ids=['SIGINT', 'SIGTERM', 'SIGHUP'])
def test_every_running_node_stops_cleanly(tmp_path: Path, sig: signal.Signals) -> None:
    commands = stop_commands(tmp_path)
    with isolated_domain() as domain, Client(domain, 'shutdown_test_client') as client:
        def answers(label: str, proc: subprocess.Popen[bytes]) -> bool:
            """The node is up and its executor spins: its parameter service answers."""
            return client.spinning(NODE_NAMES[label])

        stops = stop_after(commands, cell_environment(domain), tmp_path, sig, 0.0, answers,
                           timeout=STOP_BOUND_S)
    assert not _unclean(stops), _described(_unclean(stops))
    assert (tmp_path / 'bag' / 'metadata.yaml').exists()
    assert 'closed' in (tmp_path / f'{names.RECORDER.executable}.log').read_text()


def test_stops_spread_over_the_start(tmp_path: Path) -> None:
    bad: list[tuple[int, Stop]] = []
    for k in range(STOPS):
        sig = signal.SIGINT if k % 2 == 0 else signal.SIGTERM
        run = tmp_path / f'stop{k}'
        with isolated_domain() as domain:
            stops = stop_after(stop_commands(run), cell_environment(domain), run, sig,
                               k * STEP_S, timeout=STOP_BOUND_S)
        assert len(stops) == len(names.NODE_EXECUTABLES)
        bad += [(k, s) for s in _unclean(stops)]
    assert not bad, '\n'.join(f'stop {k}: {s.describe()}' for k, s in bad)
