"""The live calibration procedure (positioning_cell.procedures.calibration) in process, on the
positioner's own move logic over the instant simulated cell (InstantPort, no DDS): a small
program identifies the simulated machine from what the port measures and writes the file,
the mode is put back, a marker per measured pose went out; a stop asked mid-run stops the
drives, puts the mode back and writes nothing; a refused mode or a failed homing is reported
with nothing moved or written. The procedure sees only the CellPort (the truth stays in the
simulator: it judges the result here)."""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from positioning_cell import names
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.collect import Collected, Marker
from positioning_cell.calibration.identified import identify_and_write
from positioning_cell.calibration.program import ProgramSettings
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.motion.settings import machine_settings
from positioning_cell.parameters import parse
from positioning_cell.procedures import calibration as procedure
from positioning_cell.procedures import port as port_module
from positioning_cell.procedures.calibration import Outcome, Status, calibrate
from positioning_cell.procedures.port import Moved, ProcedureError, Readings
from positioning_cell.procedures.stopping import Stopped
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.testing.instant_port import InstantPort

MACHINE = machine_settings(config_path('cell.yaml'))
#: A small program: 10 fit poses, 3 hold-out, few candidates (seconds, not minutes).
PROGRAM = ProgramSettings(poses=10, hold_out=3, candidates=300)
SAMPLES = 5
#: What a procedure may ask of a port: the CellPort protocol's methods, nothing else.
PORT_METHODS = {n for n in vars(port_module.CellPort) if not n.startswith('_')}


class PortOnly:
    """The port as the procedure may see it: the CellPort's methods only (an attribute of the
    simulator, its truth, raises AttributeError), the readings without the true axis
    positions."""

    def __init__(self, port: InstantPort) -> None:
        self._port = port

    def __getattr__(self, name: str) -> Any:
        if name not in PORT_METHODS:
            raise AttributeError(f'{name}: not a CellPort method')
        return getattr(self._port, name)

    def readings(self, samples: int, timeout: float) -> Readings:
        return self._port.readings(samples, timeout)._replace(true=None)


def run(port: Any, out: Path, lines: list[str], **kwargs: Any) -> Outcome:
    return calibrate(port, MACHINE, PROGRAM, SAMPLES, out, lines.append, **kwargs)


def instant(folder: Path, cls: type[InstantPort] = InstantPort) -> InstantPort:
    """The shipped cell in process (:meth:`InstantPort.from_config`)."""
    return cls.from_config(folder)


@pytest.fixture
def port(tmp_path: Path) -> InstantPort:
    return instant(tmp_path / 'cell')


def test_a_small_program_identifies_the_machine_and_writes_the_file(
        port: InstantPort, tmp_path: Path) -> None:
    lines: list[str] = []
    progress: list[tuple[int, int, str, float]] = []
    out = tmp_path / 'calibration'
    assert port.mode() == 'measured'
    outcome = run(PortOnly(port), out, lines, load=True,
                  progress=lambda *a: progress.append(a))
    assert outcome.status is Status.WRITTEN and outcome.succeeded, outcome.reason
    assert outcome.loaded is True and outcome.path == out / 'calibration.yaml'
    # the report and the lines give the program's observability and its promise at production
    report = (out / 'calibration_report.md').read_text()
    assert '## Observability of the program measured' in report, report
    assert 'O1 (Borm & Menq)' in report and '## At the production poses' in report
    assert any(f'chosen by criterion {PROGRAM.criterion}' in line for line in lines), lines
    assert any('observability of the identified parameters' in line for line in lines), lines
    # indices of what is excited: the program's by its poses, the identified parameters' under
    # the conditions measured (the approach-driven reversal columns are not 0 there)
    for words in ('program: ', 'observability of the identified parameters'):
        line = next(line for line in lines if words in line)
        assert 'smallest singular value 0,' not in line and 'condition inf' not in line, line
    poses = PROGRAM.poses + PROGRAM.hold_out
    assert [(k, n) for k, n, _, _ in progress] == [(k, poses) for k in range(1, poses + 1)]
    assert [s for _, _, s, _ in progress] == ['fit'] * PROGRAM.poses + ['hold_out'] * 3
    # the uncompensated machine misses by tens to hundreds of µm
    assert all(1e-6 < d < 2e-3 for *_, d in progress), progress
    # every measured pose marked on /cell/calibration, with its window's start
    markers = [Marker.from_json(text) for topic, text in port.marks]
    assert {topic for topic, _ in port.marks} == {names.CALIBRATION}
    assert [m.pose for m in markers] == list(range(poses))
    assert [m.start for m in markers] == sorted(m.start for m in markers)
    assert all(m.samples == SAMPLES for m in markers)
    # mode none while measuring, put back; the positioner loaded the new file
    assert port.mode() == 'measured'
    assert port.calibration_file() == str(outcome.path.resolve())
    figures = outcome.figures
    assert figures is not None and 0.0 < figures.fit_rms < 20e-6, figures
    assert 0 < figures.identified <= figures.parameters
    # the calibrated machine predicts the hold-out poses far better than the nominal one
    doc = yaml.safe_load(outcome.path.read_text())
    hold = doc['calibration']['hold_out']
    assert hold['poses'] == 3 and hold['calibrated_rms_um'] < 0.5 * hold['nominal_rms_um'], hold
    assert np.isclose(figures.hold_out_rms * 1e6, hold['calibrated_rms_um'], atol=1e-3)
    calfile.load(outcome.path, MACHINE.mechanism)  # this mechanism's, loads
    assert any(line.startswith('calibration program: 10 poses + 3 hold-out') for line in lines)
    assert any(line.startswith('[13/13] hold_out') for line in lines)
    assert 'no recorder took the markers: this run cannot be repeated from a bag' in lines


def test_a_stop_mid_run_stops_the_drives_puts_the_mode_back_and_writes_nothing(
        port: InstantPort, tmp_path: Path) -> None:
    stop = threading.Event()
    lines: list[str] = []
    out = tmp_path / 'calibration'

    def progress(k: int, total: int, which: str, deviation: float) -> None:
        if k == 3:
            stop.set()  # as an action's cancel does, from the goal's thread

    with pytest.raises(Stopped):
        run(port, out, lines, stop=stop, progress=progress, load=True)
    assert port.stops >= 1
    moves = [c for c in port.commands if c[0] == 'move']
    assert len(moves) == 3 * 2  # approach + pose each, none after the stop
    assert port.mode() == 'measured' and port.calibration_file() == ''
    assert not out.exists()
    assert lines[-1] == 'calibration stopped: drives stopped, nothing written'


def test_a_stop_during_homing_changes_nothing(port: InstantPort, tmp_path: Path) -> None:
    stop = threading.Event()
    homing = port.home

    def home() -> Moved:
        stop.set()
        return homing()

    port.home = home  # type: ignore[method-assign]
    with pytest.raises(Stopped):
        run(port, tmp_path / 'calibration', [], stop=stop)
    assert [c[0] for c in port.commands] == ['home'] and port.mode() == 'measured'


class RefusingNone(InstantPort):
    """A positioner that refuses compensation mode none."""

    def set_mode(self, mode: str) -> None:
        if mode == 'none':
            raise ProcedureError('the positioner refused compensation.mode = none: '
                                 'a move is running')
        super().set_mode(mode)


def test_a_refused_mode_is_reported_and_nothing_moves(tmp_path: Path) -> None:
    port = instant(tmp_path / 'cell', RefusingNone)
    lines: list[str] = []
    outcome = run(port, tmp_path / 'calibration', lines)
    assert outcome.status is Status.REFUSED and outcome.path is None
    assert outcome.reason == ('the positioner refused compensation.mode = none: a move is '
                              'running')
    assert [c[0] for c in port.commands] == ['home'] and port.mode() == 'measured'
    assert lines == ['calibration: ' + outcome.reason]
    assert not (tmp_path / 'calibration').exists()


def test_a_failed_homing_is_reported_by_its_code(port: InstantPort, tmp_path: Path) -> None:
    port.home = lambda: Moved(False, 'refused_driver_silent',  # type: ignore[method-assign]
                              'no joint state')
    outcome = run(port, tmp_path / 'calibration', [])
    assert outcome.status is Status.REFUSED
    assert outcome.reason == 'homing failed: refused_driver_silent: no joint state'
    port.home = lambda: Moved(False, '', 'timed out')  # type: ignore[method-assign]
    assert run(port, tmp_path / 'calibration', []).status is Status.NOT_THERE
    assert port.mode() == 'measured' and not port.commands


def test_poses_the_tracker_does_not_measure_are_left_out_and_said(
        port: InstantPort, tmp_path: Path) -> None:
    """Every tracker window after the fourth times out: too few poses, not identified,
    nothing written, the mode put back."""
    readings = port.readings
    calls = [0]

    def flaky(samples: int, timeout: float) -> Readings:
        calls[0] += 1
        if calls[0] > 5:  # the planning reading, then four poses
            raise ProcedureError(f'timed out after {timeout:.1f} s waiting for {samples} '
                                 'tracker readings')
        return readings(samples, timeout)

    port.readings = flaky  # type: ignore[method-assign]
    lines: list[str] = []
    outcome = run(port, tmp_path / 'calibration', lines)
    assert outcome.status is Status.NOT_IDENTIFIED and outcome.path is None, outcome
    assert outcome.reason.startswith('not identified, nothing written:')
    assert len(port.marks) == 4 and port.mode() == 'measured'
    assert any(line.startswith('[5/13] fit      timed out after') and
               line.endswith(': left out') for line in lines), lines
    assert not (tmp_path / 'calibration').exists()



def _thermal_port(folder: Path) -> InstantPort:
    """The shipped cell in process with its air drifting and its sensor reading it (an
    offset drawn from 1 K, so that its reading is told from the true air)."""
    params = node_parameters(load_parameter_file(config_path()), names.NODE_MEASUREMENT)
    sim = parse(PoseMeasurementSettings, params)
    truth = replace(sim.truth, thermal=replace(sim.truth.thermal, enabled=True,
                                               sensor_offset_sigma=1.0))
    return InstantPort.from_config(folder, sim_settings=replace(sim, truth=truth))


def _measured(port: Any, out: Path, program: ProgramSettings,
              monkeypatch: pytest.MonkeyPatch) -> tuple[Collected, list[str]]:
    """What a calibration with ``program`` measured on ``port`` (taken on its way to the
    identification) and the lines it said."""
    taken: list[Collected] = []

    def keep(machine: Any, collected: Collected, *args: Any) -> Any:
        taken.append(collected)
        return identify_and_write(machine, collected, *args)

    monkeypatch.setattr(procedure, 'identify_and_write', keep)
    lines: list[str] = []
    outcome = calibrate(port, MACHINE, program, SAMPLES, out, lines.append)
    assert outcome.status is Status.WRITTEN, outcome.reason
    return taken[0], lines


def test_a_calibration_records_each_poses_temperature_and_mixed_approaches(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Alternate approaches: every axis seen from both sides; the temperature is the sensor's
    (the truth's air plus the sensor's offset, judged here), never missing."""
    port = _thermal_port(tmp_path / 'cell')
    got, lines = _measured(PortOnly(port), tmp_path / 'out', PROGRAM, monkeypatch)
    assert PROGRAM.approach_rule == 'alternate' and got.missing == ()
    approach = np.vstack([got.fit.approach, got.hold_out.approach])
    assert approach.shape == (PROGRAM.poses + PROGRAM.hold_out, 6)
    assert np.all(np.abs(approach) == 1.0), approach
    assert all({-1.0, 1.0} <= set(approach[:, j]) for j in range(6)), approach
    thermal = port.cell.truth.effects.thermal
    assert thermal is not None
    temperature = np.concatenate([got.fit.temperature, got.hold_out.temperature])
    air = thermal.air(np.linspace(0.0, port.cell.time, 200)) + thermal.sensor_offset
    noise = 5.0 * thermal.parameters.sensor_noise
    assert np.all((temperature > air.min() - noise) & (temperature < air.max() + noise)), \
        (temperature, air.min(), air.max())
    assert abs(thermal.sensor_offset) > 2.0 * noise + np.ptp(air)  # the reading, not the air
    assert not any('carry no' in line for line in lines)


def test_approached_from_below_every_leg_comes_the_same_way(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The check above can fail: from below only, each leg always lengthens into its pose."""
    got, _ = _measured(instant(tmp_path / 'cell'), tmp_path / 'out',
                       replace(PROGRAM, approach_rule='below'), monkeypatch)
    approach = np.vstack([got.fit.approach, got.hold_out.approach])
    assert all(len(set(approach[:, j])) == 1 for j in range(3)), approach
