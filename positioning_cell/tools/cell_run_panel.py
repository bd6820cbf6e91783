"""The work of ``run_cell --cell`` (:mod:`positioning_cell.tools.run_cell`: the command line):
the coordinated cell run end to end (issue 27).

Starts, on a private ROS_DOMAIN_ID on this machine's loopback, the recorder and the
coordinated cell of the cell file (:func:`positioning_cell.ros.node_sets.start_coordinated`:
each positioner's node set, the cell coordinator, the panel simulator; every node on
``--config`` then ``--cell-config``); homes every positioner and calibrates each on its own
(the program's ``positioner_calibration``); mounts the panel and relaxes it from the legs'
load cells (the program's ``relax``); calibrates the cell from the panel's targets (its
``panel_calibration``: :mod:`positioning_cell.procedures.panel_calibration`), writes the
calibrated cell file into the run folder, sets it as the coordinator's ``cell_file`` and
relaxes the panel again; drives the panel program
(:mod:`positioning_cell.procedures.panel_program`), each step recorded on
``/cell/panel_program``; stops every process; analyses the bag
(:mod:`positioning_cell.analysis.panel`: the panel's ISO 9283 figures, judged against the
simulation's truth) into ``panel_report.md`` and ``panel_report.json``; prints the table. Exit
status as ``run_cell``'s: 0 done; 1 done but a move failed, the calibration or the relax did
not hold or the analysis differs from the run; 2 a bad file (nothing started); 5 the cell did
not come up or stopped answering; 130 interrupted (the processes stopped, what was recorded
analysed)."""

from __future__ import annotations

import json
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import yaml

from positioning_cell import names
from positioning_cell.analysis.panel import (
    PANEL_TOPICS,
    panel_figures,
    read_panel_bag,
    report_lines,
)
from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.settings import CellCoordinatorSettings
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.mechanics.statics import Structure
from positioning_cell.motion.settings import CompensationMode, machine_settings
from positioning_cell.polling import wait_until
from positioning_cell.procedures import calibration, panel_calibration, panel_program
from positioning_cell.procedures.panel_program import PanelProgram, PanelStep
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.ros.cell_start import new_run_folder
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.node_sets import carried, start_panel, start_sets
from positioning_cell.ros.panel_port import RosPanelPort
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import Processes
from positioning_cell.ros.set_port import RosSetPort
from positioning_cell.tools.cell_run import in_running_cell
from positioning_cell.tools.exits import Exit
from positioning_cell.tools.interruption import Interrupted, interruptible

Say = Callable[[str], None]
#: The longest wait for the cell to come up, a homing or an answer, s.
START_TIMEOUT = 120.0
#: The window a set's load cells are heard over to say they read, s (5 to 10 readings).
LOAD_WINDOW_S = 0.1


def recorded_topics(cell: CellFile) -> list[str]:
    """What the run records: the panel's topics (:data:`PANEL_TOPICS`), /diagnostics, and each
    positioner's encoders, goals, plans, setpoints, measured and true platform and
    calibration markers (the plans and readings are what the coordinator's force watch judges
    from, the true platform what it judges: a stop can be replayed from the bag)."""
    per_set = (names.JOINT_STATES, names.TARGET, names.PLANNED_PATH, names.SETPOINT,
               names.MEASURED_POSE, names.TRUE_POSE, names.CALIBRATION)
    return [*PANEL_TOPICS, names.DIAGNOSTICS,
            *(names.in_set(t, e.name) for e in cell.positioners for t in per_set)]


def run(cell_path: Path, program_path: Path | None, config: Path | None, runs_dir: Path,
        say: Say = print, cell_config: Path | None = None) -> int:
    """The whole run (module docstring); the exit status. Every node's parameter files:
    ``config`` (default config/cell.yaml), then ``cell_config`` (default
    config/coordinated.yaml: liveness and rates for several node sets on one machine)."""
    config = config or config_path('cell.yaml')
    files = [config, cell_config or config_path('coordinated.yaml')]
    program_path = program_path or config_path('panel_program.yaml')
    try:
        cell = cell_file.load(cell_path)
        program = panel_program.load_panel_program(program_path)
        mech = CellCoordinatorSettings.from_file(config).mechanism
    except PositioningError as err:
        say(f'run_cell: error: {err}')
        return Exit.USAGE
    run_dir = new_run_folder(runs_dir)
    bag = run_dir / 'bag'
    say(f'run_cell: the coordinated cell {cell_path} ({len(cell.positioners)} positioners): '
        f'calibration of {program.calibration.poses} panel poses, then {program.steps} moves '
        f'({len(program.names)} poses x {program.settings.cycles} cycles); run folder {run_dir}')

    def work(procs: Processes, client: CellClient) -> int:
        client.advertise_program(names.PANEL_PROGRAM)
        return _drive(procs, client, cell, mech, program, files, run_dir, say)

    status = in_running_cell(run_dir, say, work)
    try:
        with interruptible():  # the analysis of what was recorded, also after an interrupt
            return _analyse(bag, run_dir, status, say, cell, mech,
                            machine_settings(config).structure)
    except Interrupted:
        say('run_cell: interrupted')
        return Exit.INTERRUPTED


def _drive(procs: Processes, client: CellClient, cell: CellFile, mech: Mechanism,
           program: PanelProgram, files: list[Path], run_dir: Path, say: Say) -> int:
    """Start (every node on the parameter ``files``), home, calibrate, drive the program; the
    exit status so far."""
    topics = recorded_topics(cell)
    procs.start(names.RECORDER.executable, params=files, overrides={names.NODE_RECORDER: {
        'output': str(run_dir / 'bag'), 'topics': topics, 'topic_pattern': ''}})
    start_sets(procs, cell, files, run_dir / 'params')
    say(f'started the recorder and {len(cell.positioners)} node sets')

    def alive() -> None:
        dead = procs.dead()
        if dead:
            raise ProcedureError(f'{", ".join(dead)} exited (see the logs)')

    def home_all() -> None:
        for entry in cell.positioners:
            alive()
            done, message = client.home(START_TIMEOUT, namespace=entry.name)
            if not done:
                raise ProcedureError(f'{entry.name}: homing failed: {message}')
        say(f'homed {", ".join(e.name for e in cell.positioners)}')

    home_all()
    status: int = Exit.OK
    if program.positioners.enabled:
        status = _calibrate_positioners(client.context.get_domain_id(), cell, program,
                                        files[0], run_dir, say)
        home_all()  # the panel is mounted on the positioners at home
    start_panel(procs, cell, files)
    # mounted once every set's load cells read it: the drives carry the panel simulator's
    # push from its first one on (a relax begun at once read none of it, in a CI)
    sets = [RosSetPort(client, e.name, START_TIMEOUT) for e in cell.positioners]

    def mounted() -> bool:
        alive()
        return all(s.load_cells(LOAD_WINDOW_S) is not None for s in sets)

    wait_until(mounted, START_TIMEOUT, "every set's load cells to read the panel")
    say('the panel mounted: the cell coordinator and the panel simulator started, every '
        "set's load cells read it")

    def up() -> bool:
        alive()
        return all(client.subscribed(t, names.NODE_RECORDER) for t in PANEL_TOPICS)

    def relax(when: str) -> bool:
        """The relax from the load cells (the program's ``relax``); whether it held."""
        if not program.settings.relax:
            return True
        done, message = client.trigger(names.COORDINATED_RELAX_FORCES, START_TIMEOUT)
        say(f'relax from the load cells ({when}): {message}')
        return bool(done)

    wait_until(up, START_TIMEOUT, 'the recorder to subscribe to the panel topics')
    with RosPanelPort(client, timeout=START_TIMEOUT, move_timeout=START_TIMEOUT) as port:
        port.ready()
        # mounted on an installation off its file, the panel is strained (kilonewtons); the
        # calibration's moves start from it relaxed
        if not relax('mounted'):
            status = Exit.NOT_ACHIEVED
        calibrated = panel_calibration.run(port, cell, mech, program.calibration, say)
        for line in panel_calibration.summary(calibrated.calibration):
            say(line)
        if calibrated.calibration.adequate:
            out = run_dir / 'cell_calibration'
            out.mkdir()
            path = (out / 'cell.yaml').resolve()
            cell = calibrated.calibration.applied(cell)
            path.write_text(yaml.safe_dump(cell.as_yaml(), sort_keys=False))
            result = client.set_parameter(names.NODE_COORDINATOR, 'cell_file', str(path))
            if not result.successful:
                raise ProcedureError(f'the coordinator refused the calibrated cell file: '
                                     f'{result.reason}')
            say(f'calibrated: {path}, loaded by the coordinator')
        else:
            say('run_cell: a positioner has more error than its model explains: the program '
                'runs on the cell file as it was')
            status = Exit.NOT_ACHIEVED

        if not relax('calibrated'):  # the calibrated file comes without the corrections
            status = Exit.NOT_ACHIEVED

        def record(step: PanelStep) -> None:
            client.publish_program(step.to_json(), names.PANEL_PROGRAM)

        steps = panel_program.run(port, cell, mech, program, record, say)
    failed = sum(not s.succeeded for s in steps)
    if failed:
        say(f'run_cell: {failed} panel move(s) failed')
        status = Exit.NOT_ACHIEVED
    return status


def _calibrate_positioners(domain: int, cell: CellFile, program: PanelProgram, config: Path,
                           run_dir: Path, say: Say) -> int:
    """Each positioner's own calibration (:func:`positioning_cell.procedures.calibration.
    calibrate`), all at once or one after the other (the program's
    ``positioner_calibration.at_once``), each through a client of its own, into
    ``run_dir/calibration/<name>``, loaded, and its compensation mode set to ``model``; a
    positioner whose calibration fails keeps its nominal model (said; NOT_ACHIEVED)."""
    settings = program.positioners
    cal = replace(ProgramSettings(), poses=settings.poses, hold_out=settings.hold_out)
    say(f'calibrating {", ".join(e.name for e in cell.positioners)}, each on its own, '
        f'{"all at once" if settings.at_once else "one after the other"}: {settings.poses} '
        f'poses + {settings.hold_out} hold-out, {settings.samples} readings each')

    def one(k: int) -> str | None:
        name = cell.positioners[k].name

        def said(line: str) -> None:
            say(f'{name}: {line}')

        machine = machine_settings(config, carried(cell, k)[names.NODE_POSITIONER])
        with CellClient(domain, f'run_cell_{name}', signals=False) as client:
            port = RosCellPort(client, START_TIMEOUT, namespace=name)
            try:
                outcome = calibration.calibrate(port, machine, cal, settings.samples,
                                                run_dir / 'calibration' / name, said, load=True)
                if not outcome.succeeded:
                    return f'{name}: its calibration failed'
                port.set_mode(CompensationMode.MODEL.value)
            except PositioningError as err:
                return f'{name}: its calibration failed: {err}'
        return None

    indices = range(len(cell.positioners))
    if settings.at_once:
        with ThreadPoolExecutor(len(indices)) as pool:
            failed = [f for f in pool.map(one, indices) if f]
    else:
        failed = [f for f in map(one, indices) if f]
    for line in failed:
        say(f'run_cell: {line}; it runs on its nominal model')
    return Exit.NOT_ACHIEVED if failed else Exit.OK


def _analyse(bag: Path, run_dir: Path, status: int, say: Say, cell: CellFile, mech: Mechanism,
             structure: Structure) -> int:
    if not bag.exists():
        say(f'run_cell: no bag was recorded (logs in {run_dir / "logs"})')
        return status or Exit.NOT_THERE
    say(f'analysing {bag}')
    try:
        recording = read_panel_bag(bag, [e.name for e in cell.positioners])
        figures = panel_figures(recording, cell, mech, structure)
    except PositioningError as err:
        say(f'run_cell: analysis failed: {err}')
        return status or Exit.NOT_ACHIEVED
    lines = report_lines(figures)
    (run_dir / 'panel_report.md').write_text('\n'.join(lines) + '\n')
    (run_dir / 'panel_report.json').write_text(json.dumps(figures.to_dict(), indent=1))
    for line in lines:
        say(line)
    say(f'bag:     {bag}\nreport:  {run_dir / "panel_report.md"}')
    if status == Exit.OK and not figures.same_as_live:
        status = Exit.NOT_ACHIEVED
    return status
