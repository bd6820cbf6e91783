"""The run's program on a running cell (``run_cell``, ``make run``), through a
:class:`~positioning_cell.procedures.port.CellPort`: the calibration the program asks for (the
cell identifies itself and the positioner loads the result; judged against the simulator's
truth of the parameter file, :mod:`.judging`), the axis test if asked
(:mod:`positioning_cell.procedures.axis_test`), then the program of ``config/program.yaml``:
per compensation mode, the mode set on the positioner; per move, the step published on
``/cell/program`` (JSON of :class:`~positioning_cell.analysis.program.ProgramStep`, kept for a
recorder, so the analysis knows the mode and pose of every move), the move, the accuracy
monitor's verdict on it, and a line to the caller; then the program's static compliance
test if it has one (:mod:`positioning_cell.procedures.compliance_test`). Starting the cell and
analysing the recording are the caller's."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import NamedTuple, Protocol

from positioning_cell import names
from positioning_cell.analysis.axis_test import AxisTest, AxisTestResults
from positioning_cell.analysis.program import Program, ProgramStep
from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import CompensationMode, PositionerSettings, machine_settings
from positioning_cell.procedures import calibration
from positioning_cell.procedures.axis_test import run_axis_test, write
from positioning_cell.procedures.compliance_test import run_compliance_test
from positioning_cell.procedures.judging import judge_calibration
from positioning_cell.procedures.port import CellPort, ProcedureError, Say, moved_or_raise

#: The report's note on the compensated modes, by how the run's calibration went.
NO_CALIBRATION = ('No calibration in this run: `model` and `measured` use the a-priori '
                  'clearance model of the config (positioner.compensation.clearance).')
CALIBRATION_FAILED = ('The calibration failed: `model` and `measured` use the a-priori '
                      'clearance model of the config.')


class Calibrator(Protocol):
    """The calibration procedure as the run calls it: on the cell of ``port``, the machine
    ``machine`` (the positioner's nominal settings) measured at ``settings.poses`` +
    ``settings.hold_out`` poses, ``samples`` tracker readings each, the result written in
    ``out`` and loaded by the positioner; the calibration file, or None when the data did not
    identify the machine. ProcedureError when the cell refused or did not complete it."""

    def __call__(self, port: CellPort, machine: PositionerSettings,
                 settings: ProgramSettings, samples: int, out: Path, say: Say) -> Path | None:
        ...


def calibrate_and_load(port: CellPort, machine: PositionerSettings, settings: ProgramSettings,
                       samples: int, out: Path, say: Say) -> Path | None:
    """The run's :class:`Calibrator`: the calibration procedure
    (:func:`positioning_cell.procedures.calibration.calibrate`), its file loaded by the
    positioner; None when it was not written and loaded."""
    outcome = calibration.calibrate(port, machine, settings, samples, out, say, load=True)
    return outcome.path if outcome.succeeded else None


class Driven(NamedTuple):
    """How the program's moves went: ``failed`` moves (refused, aborted or settled out of
    tolerance), moves ``skipped`` because the positioner refused their mode, the refused
    modes with the positioner's reason, and ``unjudged`` moves the monitor gave no verdict
    on within the program's settle timeout."""

    failed: int
    skipped: int
    refused_modes: tuple[tuple[str, str], ...]
    unjudged: int


class RunOutcome(NamedTuple):
    """A completed run: the program's moves (:class:`Driven`); the report's ``note`` on the
    compensated modes; the calibration file the run made (None: none made or it failed);
    the axis test's figures (None: not asked, or ``axis_test_failed``); whether the
    program's compliance test failed."""

    driven: Driven
    note: str
    calibration: Path | None
    axis_test: AxisTestResults | None
    axis_test_failed: bool
    compliance_failed: bool = False

    @property
    def achieved(self) -> bool:
        """Every move done, every mode taken, the axis test and the compliance test (if asked)
        completed (a move the monitor gave no verdict on counts as done: its figures are the
        analysis's)."""
        d = self.driven
        return not (d.failed or d.skipped or d.refused_modes or self.axis_test_failed
                    or self.compliance_failed)


def calibrate(port: CellPort, program: Program, config: Path, run_dir: Path, say: Say,
              calibrator: Calibrator) -> tuple[str, Path | None]:
    """The run's calibration (``program.calibration``, through ``calibrator``, into
    ``run_dir/calibration``), judged against the simulator's truth of ``config``: the note the
    report gives the compensated modes and the calibration file (None: none, or it failed)."""
    cal = program.calibration
    if cal is None:
        return NO_CALIBRATION, None
    say(f'calibrating: {cal.poses} poses + {cal.hold_out} hold-out, {cal.samples} tracker '
        'readings each')
    settings = replace(ProgramSettings(), poses=cal.poses, hold_out=cal.hold_out)
    try:
        path = calibrator(port, machine_settings(config), settings, cal.samples,
                          run_dir / 'calibration', say)
    except PositioningError as err:  # ProcedureError included
        say(f'calibration failed: {err}')
        path = None
    if path is None:
        return CALIBRATION_FAILED, None
    judged = judge_calibration(path, config)
    if judged is not None:
        table, summary = judged
        say(f'truth table: {table}: {summary}')
    return (f'`model` and `measured` use the machine the cell identified from its own '
            f'measurements in this run ({path.relative_to(run_dir)}); only the truth table '
            'reads the simulator.'), path


def axis_test(port: CellPort, test: AxisTest, config: Path, run_dir: Path,
              say: Say) -> AxisTestResults | None:
    """The run's axis test (:mod:`positioning_cell.procedures.axis_test`): a line per measured
    stop, then the ISO 230-2 table of each axis, written to ``axis_test.md`` and
    ``axis_test.json`` in ``run_dir``. None when it could not be completed (the positioner is
    asked to home so that the run continues)."""
    try:
        results = run_axis_test(port, test, config, say).results
    except PositioningError as err:  # ProcedureError included
        say(f'axis test failed: {err}')
        port.home()
        return None
    md, js = write(results, run_dir)
    say('axis test, ISO 230-2:2014 per axis (x = actual - commanded):')
    say('\n'.join(results.summary()))
    say('\n'.join(results.markdown()))
    say(f'axis test: {md}, {js}')
    return results


def drive(port: CellPort, program: Program, note: str, say: Say) -> Driven:
    """The program (module docstring): per mode, set it (a refused mode: said, its moves
    skipped); per move, the step marked on ``/cell/program`` (with ``note`` for the
    compensated modes), the move, the monitor's verdict, a line; at the end, however it
    ends, the end-of-program marker. ProcedureError when the positioner gives no answer to a
    move (the cell is not there)."""
    failed = skipped = unjudged = 0
    refused: list[tuple[str, str]] = []
    width = len(str(program.moves))
    begin = port.now()
    mode_taken, current = True, None
    try:
        for n, (mode, cycle, k) in enumerate(program.steps(), start=1):
            if mode != current:
                current = mode
                try:
                    port.set_mode(mode)
                except ProcedureError as err:
                    refused.append((mode, str(err)))
                    left = program.cycles * len(program.order)
                    say(f'compensation mode: {mode} refused: {err}; its {left} moves left out')
                    mode_taken = False
                else:
                    say(f'compensation mode: {mode}')
                    mode_taken = True
            if not mode_taken:
                skipped += 1
                continue
            name = program.names[k]
            port.mark(names.PROGRAM, ProgramStep(
                mode, port.now(), cycle, name,
                note if mode != CompensationMode.NONE.value else None).to_json())
            before = port.seen()
            started = port.now()
            moved = port.move(program.position[k], program.quaternion[k], program.tolerance)
            took = port.now() - started
            head = f'[{n:>{width}}/{program.moves}] {mode:<8} cycle {cycle} {name:<4}'
            if not moved.success:
                if not moved.code:  # no answer at all: the positioner is not there
                    moved_or_raise(moved, f'move to {name}')
                failed += 1
                say(f'{head} move refused or aborted: {moved.code}: {moved.reason}')
                continue
            verdict = port.verdict(before, program.settle_timeout)
            if verdict is None:
                unjudged += 1
                verdict = f'monitor saw no settled pose within {program.settle_timeout:.0f} s'
            say(f'{head} moved in {took:.1f} s; monitor: {verdict} [{port.now() - begin:.0f} s]')
    finally:  # what moves next (homing, a calibration, another program) is not this program
        port.mark(names.PROGRAM, ProgramStep.ended(port.now()).to_json())
    return Driven(failed, skipped, tuple(refused), unjudged)


def compliance(port: CellPort, program: Program, say: Say) -> bool:
    """The program's compliance test at its pose, if it has one: False when it failed (said,
    with the reason)."""
    test = program.compliance
    if test is None:
        return True
    k = program.names.index(test.pose)
    try:
        run_compliance_test(port, test, program.position[k], program.quaternion[k], say)
    except PositioningError as err:  # ProcedureError included
        say(f'compliance test failed: {err}')
        return False
    return True


def run_program(port: CellPort, program: Program, config: Path, run_dir: Path, say: Say, *,
                calibrator: Calibrator, axis_test_plan: AxisTest | None = None) -> RunOutcome:
    """The run (module docstring) on the cell of ``port`` configured by ``config``: the
    calibration (through ``calibrator``), the axis test ``axis_test_plan`` (None: none), the
    program and its compliance test; what it writes goes to ``run_dir``. ProcedureError when
    the cell stops answering."""
    note, calibration = calibrate(port, program, config, run_dir, say, calibrator)
    results = (None if axis_test_plan is None
               else axis_test(port, axis_test_plan, config, run_dir, say))
    driven = drive(port, program, note, say)
    return RunOutcome(driven, note, calibration, results,
                      axis_test_plan is not None and results is None,
                      not compliance(port, program, say))
