"""The run's program (positioning_cell.procedures.program_run, what ``make run`` drives) in
process, without DDS: the in-process port (positioning_cell.testing.instant_port: the positioner's
own mover on drives that arrive at once, the simulated tracker, the monitor's verdict rule) on
the shipped cell. The steps marked on /cell/program, a line with the verdict per move, failed
moves counted, a refused mode reported and its moves left out, the calibration's note and
truth table, the axis test between the calibration and the modes."""

from __future__ import annotations

import dataclasses
import itertools
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from exact_calibration import exact_calibration

from positioning_cell import names
from positioning_cell.analysis.axis_test import AxisPlan, AxisTest, AxisTestMarker
from positioning_cell.analysis.compliance_test import ComplianceTest
from positioning_cell.analysis.program import Calibrating, Program, ProgramStep
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.program import ProgramSettings
from positioning_cell.config import config_path
from positioning_cell.motion.settings import PositionerSettings, machine_settings
from positioning_cell.procedures.judging import simulator
from positioning_cell.procedures.port import CellPort, Moved, ProcedureError
from positioning_cell.procedures.program_run import (
    CALIBRATION_FAILED,
    NO_CALIBRATION,
    drive,
    run_program,
)
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.testing.instant_port import InstantPort

#: Three poses of the shipped program's ISO 9283 cube (base frame, m; home orientation).
POSES = {'P1': (0.0, 0.0, 0.196), 'P2': (0.004, 0.004, 0.2), 'P3': (-0.004, -0.004, 0.192)}
MODES = ('none', 'model', 'measured')
HOME_Q = (0.0, 0.0, 0.0, 1.0)
#: A run's line's verdict: |Δp| ± U (k = 2) µm, the angle, the decision (ISO 14253-1).
VERDICT = re.compile(r'monitor: \|Δp\| (\d+\.\d) ± (\d+\.\d) µm, \d\.\d{4}°: '
                     r'(conforms|indeterminate|does not conform) \[\d+ s\]$')


def _program(poses: dict[str, tuple[float, float, float]] = POSES, cycles: int = 1,
             calibration: Calibrating | None = None) -> Program:
    """A program of ``poses`` (not checked against the limits: a test may ask the
    impossible) in the three modes."""
    return Program(tuple(poses), np.array(list(poses.values())),
                   np.tile(HOME_Q, (len(poses), 1)), cycles, MODES, calibration=calibration)


class Port(InstantPort):
    """The in-process cell, noting the mode each move ran in, refusing the modes in
    ``refuse`` and not answering the moves to the positions in ``silent``."""

    refuse: set[str]
    silent: set[tuple[float, ...]]
    move_modes: list[str]

    def set_mode(self, mode: str) -> None:
        if mode in self.refuse:
            raise ProcedureError(f'the positioner refused compensation.mode = {mode}: '
                                 'the tracker is silent')
        super().set_mode(mode)

    def move(self, position: object, quaternion: object, tolerance: float = 0.0) -> Moved:
        if tuple(np.asarray(position, float)) in self.silent:
            return Moved(False, '', 'the response of /positioner/move_to_pose did not come')
        self.move_modes.append(self.mode())
        return super().move(position, quaternion, tolerance)  # type: ignore[arg-type]


def _port(folder: Path, sim_settings: PoseMeasurementSettings | None = None) -> Port:
    made = Port.from_config(folder, sim_settings=sim_settings)
    assert isinstance(made, Port)
    made.refuse, made.silent, made.move_modes = set(), set(), []
    return made


@pytest.fixture
def port(tmp_path: Path) -> Port:
    return _port(tmp_path)


def _marked(port: InstantPort) -> list[ProgramStep]:
    """Everything marked on /cell/program, the end-of-program markers included."""
    return [ProgramStep.from_json(text, 0.0) for topic, text in port.marks
            if topic == names.PROGRAM]


def _steps(port: InstantPort) -> list[ProgramStep]:
    """The program steps marked (no end-of-program marker)."""
    return [s for s in _marked(port) if not s.end]


def _never(*args: object) -> Path | None:
    raise AssertionError('no calibration was asked for')


def test_each_move_is_marked_moved_and_judged_in_its_mode(port: Port, tmp_path: Path) -> None:
    lines: list[str] = []
    outcome = run_program(port, _program(cycles=2), config_path(), tmp_path, lines.append,
                          calibrator=_never)
    assert outcome.achieved and outcome.note == NO_CALIBRATION
    assert outcome.driven == (0, 0, (), 0) and outcome.calibration is None
    assert outcome.axis_test is None and not outcome.axis_test_failed
    expected = [(mode, cycle, name) for mode in MODES for cycle in (1, 2) for name in POSES]
    # the steps on /cell/program, in order, before their moves; the note with compensation
    steps = _steps(port)
    assert [(s.mode, s.cycle, s.pose) for s in steps] == expected
    assert [s.note for s in steps] == [None if m == 'none' else NO_CALIBRATION
                                       for m, _, _ in expected]
    assert all(b.stamp >= a.stamp for a, b in itertools.pairwise(steps))
    # then, once, the end of the program: what moves after it is no program's
    end = _marked(port)[-1]
    assert end.end and end.stamp >= steps[-1].stamp and len(_marked(port)) == len(steps) + 1
    # each move in its mode, to its pose
    assert port.move_modes == [m for m, _, _ in expected]
    moves = [what for kind, what, _ in port.commands if kind == 'move']
    for (_, _, name), (p, q) in zip(expected, moves, strict=True):  # type: ignore[misc]
        np.testing.assert_array_equal(p, POSES[name])
        np.testing.assert_array_equal(q, HOME_Q)
    # a line per mode and per move, with the monitor's verdict
    assert [line for line in lines if line.startswith('compensation mode')] == [
        f'compensation mode: {m}' for m in MODES]
    said = [line for line in lines if line.startswith('[')]
    assert len(said) == 18
    errors: dict[str, list[float]] = {m: [] for m in MODES}
    for n, ((mode, cycle, name), line) in enumerate(zip(expected, said, strict=True), start=1):
        assert line.startswith(f'[{n:>2}/18] {mode:<8} cycle {cycle} {name:<4} moved in '), line
        verdict = VERDICT.search(line)
        assert verdict is not None, line
        errors[mode].append(float(verdict[1]))
        # the closed loop settles within the monitor's 50 µm, by more than its reading's U;
        # uncompensated the shipped machine's geometry error (hundreds of µm) is far outside
        assert (verdict[3] == 'conforms') == (mode == 'measured'), line
        assert 0.0 < float(verdict[2]) < 25.0, line
        if mode == 'none':
            assert verdict[3] == 'does not conform', line
    assert min(errors['none']) > 100.0 and max(errors['measured']) < 20.0


def test_failed_moves_are_counted_and_a_refused_mode_is_left_out(port: Port,
                                                                 tmp_path: Path) -> None:
    poses = dict(POSES, P4=(0.0, 0.0, 0.3))  # beyond the legs' stroke: refused_limits
    port.refuse = {'model'}
    lines: list[str] = []
    outcome = run_program(port, _program(poses), config_path(), tmp_path, lines.append,
                          calibrator=_never)
    assert not outcome.achieved
    driven = outcome.driven
    assert driven.failed == 2 and driven.skipped == 4 and driven.unjudged == 0
    assert driven.refused_modes == (('model', 'the positioner refused compensation.mode = '
                                     'model: the tracker is silent'),)
    assert ('compensation mode: model refused: the positioner refused compensation.mode = '
            'model: the tracker is silent; its 4 moves left out') in lines
    refused = [line for line in lines if 'move refused or aborted' in line]
    assert [line.split(']')[0] for line in refused] == ['[ 4/12', '[12/12']
    assert all(': refused_limits: path refused, outside limits' in line for line in refused)
    # nothing of the refused mode was marked or moved; the measured mode still ran
    assert [s.mode for s in _steps(port)] == ['none'] * 4 + ['measured'] * 4
    assert port.move_modes == ['none'] * 4 + ['measured'] * 4


def test_a_sequence_visits_its_poses_in_its_order_repeats_included(port: Port,
                                                                    tmp_path: Path) -> None:
    """A program's ``sequence`` (config/acceptance.yaml): each cycle visits P2, P1, P3, P1;
    a refused mode leaves out the sequence's moves of every cycle."""
    port.refuse = {'model'}
    program = dataclasses.replace(_program(cycles=2), sequence=(1, 0, 2, 0))
    lines: list[str] = []
    outcome = run_program(port, program, config_path(), tmp_path, lines.append,
                          calibrator=_never)
    assert outcome.driven.skipped == 8 and outcome.driven.failed == 0
    assert ('compensation mode: model refused: the positioner refused compensation.mode = '
            'model: the tracker is silent; its 8 moves left out') in lines
    order = ['P2', 'P1', 'P3', 'P1'] * 2
    assert [(s.mode, s.pose) for s in _steps(port)] == [(m, name) for m in ('none', 'measured')
                                                         for name in order]
    moves = [what for kind, what, _ in port.commands if kind == 'move']
    for name, (p, _) in zip(order * 2, moves, strict=True):  # type: ignore[misc]
        np.testing.assert_array_equal(p, POSES[name])


def test_a_move_without_an_answer_ends_the_run(port: Port) -> None:
    port.silent = {POSES['P2']}
    lines: list[str] = []
    with pytest.raises(ProcedureError, match='move to P2: no answer: the response of '
                       '/positioner/move_to_pose did not come'):
        drive(port, _program(), 'note', lines.append)
    assert len([line for line in lines if line.startswith('[')]) == 1
    assert [s.end for s in _marked(port)] == [False, False, True]  # ended there all the same


def test_the_calibration_is_loaded_judged_and_noted(tmp_path: Path) -> None:
    """A calibrator that identifies the machine exactly: the compensated modes use it (the
    model mode comes close to the truth), the run's note says so, the truth table is written
    from the config's simulator; a failed calibration leaves the a-priori model. The machine
    is exactly of the identified model (its effects outside it off), so that an exact
    calibration exists."""
    sim_settings = simulator(config_path())
    assert sim_settings is not None
    sim_settings = replace(sim_settings, truth=sim_settings.truth.without_effects())
    port = _port(tmp_path, sim_settings)
    truth = sim_settings.true_machine()
    asked: list[tuple[PositionerSettings, ProgramSettings, int, Path]] = []

    def calibrator(port: CellPort, machine: PositionerSettings, settings: ProgramSettings,
                   samples: int, out: Path, say: object) -> Path | None:
        asked.append((machine, settings, samples, out))
        path = exact_calibration(truth, machine.mechanism, out / 'calibration.yaml')
        taken, reason = port.load_calibration(str(path))
        assert taken, reason
        return path

    lines: list[str] = []
    outcome = run_program(port, _program(calibration=Calibrating(12, 3, 5)), config_path(),
                          tmp_path, lines.append, calibrator=calibrator)
    assert lines[0] == 'calibrating: 12 poses + 3 hold-out, 5 tracker readings each'
    ((machine, settings, samples, out),) = asked
    assert machine == machine_settings(config_path())
    assert (settings.poses, settings.hold_out, samples) == (12, 3, 5)
    assert out == tmp_path / 'calibration'
    assert outcome.calibration == out / 'calibration.yaml'
    assert outcome.note.startswith('`model` and `measured` use the machine the cell '
                                   'identified from its own measurements in this run '
                                   '(calibration/calibration.yaml)')
    table = out / 'truth.md'
    assert lines[1] == (f'truth table: {table}: {cp.FORMAT1_COUNT} of {cp.FORMAT1_COUNT} '
                        'identified geometric parameters within 3 sigma of the truth')
    assert '| parameter | identified | sigma | truth |' in table.read_text()
    assert [s.note for s in _steps(port)] == [None] * 3 + [outcome.note] * 6
    model = [float(m[1]) for line in lines if ' model ' in line
             and (m := VERDICT.search(line)) is not None]
    assert len(model) == 3 and max(model) < 20.0  # the identified machine, open loop

    def failing(*args: object) -> Path | None:
        raise ProcedureError('homing: refused_drives_off: the drives are off',
                             'refused_drives_off')

    lines.clear()
    outcome = run_program(port, _program(calibration=Calibrating(12, 3, 5)), config_path(),
                          tmp_path, lines.append, calibrator=failing)
    assert outcome.note == CALIBRATION_FAILED and outcome.calibration is None
    assert lines[1] == 'calibration failed: homing: refused_drives_off: the drives are off'
    assert outcome.achieved  # the program itself ran


def test_the_axis_test_runs_after_the_calibration_and_before_the_modes(
        port: Port, tmp_path: Path) -> None:
    test = AxisTest((AxisPlan('leg1_length', (-0.0005, 0.0005), 0.0002),), cycles=2,
                    samples=3, dwell=0.0)
    lines: list[str] = []
    outcome = run_program(port, _program(), config_path(), tmp_path, lines.append,
                          calibrator=_never, axis_test_plan=test)
    assert outcome.achieved and outcome.axis_test is not None
    markers = [AxisTestMarker.from_json(text) for topic, text in port.marks
               if topic == names.AXIS_TEST]
    assert len(markers) == 8 and outcome.axis_test.run == markers[0].run
    assert (tmp_path / 'axis_test.md').is_file() and (tmp_path / 'axis_test.json').is_file()
    first_move = lines.index('compensation mode: none')
    assert lines.index('axis test, ISO 230-2:2014 per axis (x = actual - commanded):') \
        < first_move
    assert [topic for topic, _ in port.marks] == [names.AXIS_TEST] * 8 + [names.PROGRAM] * 10
    # an axis test the positioner will not run: said, and the program still runs
    port.refuse = {'none'}
    port.marks.clear()
    lines.clear()
    outcome = run_program(port, _program(), config_path(), tmp_path, lines.append,
                          calibrator=_never, axis_test_plan=test)
    assert outcome.axis_test is None and outcome.axis_test_failed and not outcome.achieved
    assert lines[1] == ('axis test failed: the positioner refused compensation.mode = none: '
                        'the tracker is silent')
    assert port.commands[-7][0] == 'home'  # homed after it, before the program
    assert [s.mode for s in _steps(port)] == ['model'] * 3 + ['measured'] * 3


def test_the_compliance_test_runs_after_the_modes_and_its_failure_counts(
        port: Port, tmp_path: Path) -> None:
    """A program's compliance: block runs after the end-of-program marker, its markers on
    /cell/compliance_test; a load the rig refuses fails it (said) and the run is not
    achieved."""
    program = dataclasses.replace(_program(), modes=('model',), compliance=ComplianceTest(
        pose='P1', load=20.0, steps=2, directions=('+x', '-z'), samples=3))
    lines: list[str] = []
    outcome = run_program(port, program, config_path(), tmp_path, lines.append,
                          calibrator=_never)
    assert outcome.achieved and not outcome.compliance_failed
    topics = [topic for topic, _ in port.marks]
    end = max(i for i, t in enumerate(topics) if t == names.PROGRAM)
    assert topics[end + 1:] == [names.COMPLIANCE_TEST] * 6
    assert ProgramStep.from_json(port.marks[end][1], 0.0).end
    assert sum(line.startswith('compliance ') for line in lines) == 2
    refused = dataclasses.replace(program, compliance=ComplianceTest(load=5000.0))
    lines.clear()
    outcome = run_program(port, refused, config_path(), tmp_path, lines.append,
                          calibrator=_never)
    assert outcome.compliance_failed and not outcome.achieved
    assert any(line.startswith('compliance test failed: load rig: 1500.0 N is beyond')
               for line in lines), lines
