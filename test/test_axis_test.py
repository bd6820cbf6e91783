"""The axis test (ISO 230-2 per actuator): the program file (parsing, refusals, limits), the
stops in the standard's linear cycle order, the markers' JSON, the figures from markers, and
the whole procedure (positioning_cell.procedures.axis_test) on a simulated machine without
ROS: the in-process port (positioning_cell.testing.instant_port: the positioner's own mover and
jog on drives that arrive at once, the simulated tracker), a machine with known zero offsets."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
import yaml
from exact_calibration import exact_calibration
from scipy.spatial.transform import Rotation

from positioning_cell import names
from positioning_cell.accuracy.iso230_2 import iso230_2
from positioning_cell.analysis.axis_test import (
    DOWN,
    TRACKER,
    TRUTH,
    UP,
    AxisPlan,
    AxisTest,
    AxisTestMarker,
    actuator_uncertainty,
    axis_test_figures,
    axis_test_from,
    home_joints,
    load_axis_test,
    parse_markers,
)
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse_jacobian
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.motion.settings import machine_settings
from positioning_cell.parameters import parse
from positioning_cell.procedures.axis_test import (
    ModeRefusedError,
    Reference,
    run_axis_test,
    run_procedure,
    write,
)
from positioning_cell.procedures.judging import simulation_truth, simulator
from positioning_cell.procedures.port import Moved, ProcedureError
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.sim.truth import TruthParameters
from positioning_cell.testing.instant_port import InstantPort
from positioning_cell.tools.interruption import Interrupted

MECH = Mechanism.default()
SHIPPED = config_path('axis_test.yaml')


def _doc(**axes: Any) -> dict[str, Any]:
    return {'axis_test': {'cycles': 2, 'samples': 3, 'dwell': 0.0, 'axes': axes}}


# -- the program ---------------------------------------------------------------------------------
def test_the_shipped_axis_test_is_iso_230_2s_minimum_on_every_axis() -> None:
    test = load_axis_test(SHIPPED, MECH)
    assert [p.axis for p in test.axes] == list(JOINT_NAMES)
    assert test.cycles == 5 and all(len(p.targets) == 5 for p in test.axes)
    assert test.measured_stops == 300
    for plan in test.axes:  # irregular spacing: no two gaps alike
        gaps = np.round(np.diff(plan.targets), 9)
        assert len(set(gaps.tolist())) == len(gaps), plan.axis
    # the jog speeds and the settle time of config/cell.yaml: a few minutes
    minutes = test.duration(0.002, 0.01, 0.02, 0.1, 0.2, 20.0, 0.18) / 60.0
    assert 4.0 < minutes < 8.0


@pytest.mark.parametrize(('doc', 'message'), [
    ({}, 'no "axis_test:" mapping'),
    ({'axis_test': {'axes': {}}}, 'axis_test.axes: expected a mapping of joint names'),
    ({'axis_test': {'axes': {'leg1_length': {'targets': [0.0, 0.001], 'overshoot': 1e-4}},
                    'speed': 1}}, r'axis_test.speed: unknown key'),
    (_doc(leg4_length={'targets': [0.0, 0.001], 'overshoot': 1e-4}),
     'axis_test.axes.leg4_length: unknown axis: one of leg1_length'),
    (_doc(leg1_length={'targets': [0.0], 'overshoot': 1e-4}),
     r'axis_test.axes.leg1_length.targets = \[0.0\]: a list of at least 2'),
    (_doc(leg1_length={'targets': [0.0, 0.001, 0.001], 'overshoot': 1e-4}),
     r'targets\[2\] = 0.001: the targets must be strictly increasing'),
    (_doc(leg1_length={'targets': [0.0, 'x'], 'overshoot': 1e-4}),
     r"targets\[1\] = 'x': must be a finite number"),
    (_doc(leg1_length={'targets': [0.0, float('nan')], 'overshoot': 1e-4}),
     r'targets\[1\] = nan: must be a finite number'),
    (_doc(leg1_length={'targets': [0.0, 0.001], 'overshoot': 0.0}),
     r'leg1_length.overshoot = 0.0: must be a number > 0'),
    (_doc(leg1_length={'targets': [0.0, 0.001]}), r'overshoot = None: must be a number > 0'),
    (_doc(leg1_length={'targets': [0.0, 0.001], 'overshoot': 1e-4, 'speed': 1}),
     r'leg1_length.speed: unknown key'),
    ({'axis_test': {'cycles': 1, 'axes': {'leg1_length': {'targets': [0.0, 0.001],
                                                          'overshoot': 1e-4}}}},
     r'axis_test.cycles = 1: must be an integer >= 2'),
    ({'axis_test': {'samples': True, 'axes': {'leg1_length': {'targets': [0.0, 0.001],
                                                              'overshoot': 1e-4}}}},
     r'axis_test.samples = True: must be an integer >= 1'),
    ({'axis_test': {'dwell': -1, 'axes': {'leg1_length': {'targets': [0.0, 0.001],
                                                          'overshoot': 1e-4}}}},
     r'axis_test.dwell = -1: must be a number >= 0'),
    # the stroke: home 200 mm, longest leg 220 mm
    (_doc(leg2_length={'targets': [0.0, 0.0199], 'overshoot': 0.0002}),
     r'leg2_length: the stop at \+20.1000 mm from home takes the axis to \+220.1000 mm, '
     r'outside its range \[\+180.0000 mm, \+220.0000 mm\]'),
    # within the θ range (±785 mrad) but no pose of the machine there
    (_doc(leg1_theta={'targets': [0.3, 0.75], 'overshoot': 0.001}),
     r'leg1_theta: at \+7\d\d.\d+ mrad from home the platform leaves the workspace'),
    # a pose, but the spherical joint of leg 1 tilts beyond 60 degrees
    (_doc(leg1_theta={'targets': [0.2, 0.6], 'overshoot': 0.001}),
     r'leg1_theta: at \+600.0000 mrad from home, with the other joints at home, the platform '
     r'is outside the limits: leg 1 spherical-joint tilt 60.39\d+ deg above the maximum'),
])
def test_a_bad_program_is_refused_with_the_reason(doc: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        axis_test_from(doc, MECH)


def test_the_program_file_is_read_and_the_travel_checked(tmp_path: Path) -> None:
    path = tmp_path / 'axis.yaml'
    path.write_text(yaml.safe_dump(_doc(leg3_theta={'targets': [-0.002, 0.001, 0.003],
                                                    'overshoot': 0.001})))
    test = load_axis_test(path, MECH)
    assert test == AxisTest((AxisPlan('leg3_theta', (-0.002, 0.001, 0.003), 0.001),), 2, 3, 0.0)
    with pytest.raises(ConfigError, match=r"parameter file '.*missing\.yaml': cannot be read"):
        load_axis_test(tmp_path / 'missing.yaml', MECH)


def test_the_stops_follow_the_linear_cycle_of_iso_230_2() -> None:
    test = AxisTest((AxisPlan('leg1_length', (-1.0, 0.5, 2.0), 0.25),), cycles=2)
    stops = [(s.position, s.measured, s.index, s.direction, s.cycle) for s in test.stops()]
    assert stops == [
        (-1.25, False, None, DOWN, 0),                                   # below P_1
        (-1.0, True, 0, UP, 1), (0.5, True, 1, UP, 1), (2.0, True, 2, UP, 1),
        (2.25, False, None, UP, 1),                                      # beyond P_m
        (2.0, True, 2, DOWN, 1), (0.5, True, 1, DOWN, 1), (-1.0, True, 0, DOWN, 1),
        (-1.25, False, None, DOWN, 1),                                   # below P_1 again
        (-1.0, True, 0, UP, 2), (0.5, True, 1, UP, 2), (2.0, True, 2, UP, 2),
        (2.25, False, None, UP, 2),
        (2.0, True, 2, DOWN, 2), (0.5, True, 1, DOWN, 2), (-1.0, True, 0, DOWN, 2),
        (0.0, False, None, UP, 0)]                                       # home
    # every measured stop is approached in its direction: from below going up, from above
    # going down
    here = 0.0
    for s in test.stops():
        if s.measured:
            assert (s.position > here) == (s.direction == UP)
        here = s.position
    assert test.measured_stops == 12


# -- markers -----------------------------------------------------------------------------------
def _marker(**kw: Any) -> AxisTestMarker:
    base: dict[str, Any] = {
        'run': '2026-01-01T00:00:00.000+00:00', 'axis': 'leg1_length', 'index': 0,
        'target': -0.001, 'direction': UP, 'cycle': 1, 'commanded': 0.199, 'encoder': 0.199,
        'tracker': 0.19905, 'true': 0.19904, 'start': 10.0, 'end': 10.25, 'samples': 5,
        'reference': 'calibrated'}
    base.update(kw)
    return AxisTestMarker(**base)


def test_a_marker_round_trips_through_json() -> None:
    for marker in (_marker(), _marker(true=None, reference='nominal', direction=DOWN),
                   _marker(tracker_u=2.5e-6)):
        text = marker.to_json()
        assert AxisTestMarker.from_json(text) == marker
        assert json.loads(text)['true'] == marker.true
    # a marker recorded before the uncertainty was: none stated
    old = json.loads(_marker().to_json())
    del old['tracker_u']
    assert AxisTestMarker.from_json(json.dumps(old)).tracker_u is None
    assert _marker().deviation(TRACKER) == pytest.approx(5e-5)
    assert _marker().deviation(TRUTH) == pytest.approx(4e-5)
    assert _marker(true=None).deviation(TRUTH) is None


@pytest.mark.parametrize(('text', 'message'), [
    ('not json', 'not an axis-test marker'),
    (json.dumps({'axis': 'leg1_length'}), "not an axis-test marker.*'run, index, target, "),
    (_marker(axis='leg9').to_json(), r'\(unknown axis\)'),
    (_marker(direction='left').to_json(), r'\(direction not up or down\)'),
    (_marker(cycle=0).to_json(), r'\(index, cycle or samples out of range\)'),
    (_marker(reference='guessed').to_json(), r'\(reference not calibrated or nominal\)'),
    (_marker(tracker=float('nan')).to_json(), r'\(a value is not finite\)'),
    (_marker(tracker_u=-1e-6).to_json(), r'\(tracker_u negative or not finite\)'),
])
def test_a_bad_marker_is_refused(text: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        AxisTestMarker.from_json(text)
    markers, problems = parse_markers([_marker().to_json(), text])
    assert markers == [_marker()] and len(problems) == 1


# -- the figures from markers -----------------------------------------------------------------
def _markers_of(axis: str, targets: np.ndarray, x_up: np.ndarray, x_down: np.ndarray,
                home: float, run: str = 'r1', true: np.ndarray | None = None,
                t0: float = 0.0) -> list[AxisTestMarker]:
    """Markers of one axis with deviations x (n, m) (tracker; ``true``: (2, n, m) or None)."""
    out, t = [], t0
    n, m = x_up.shape
    for c in range(n):
        for direction, x, order in ((UP, x_up, range(m)), (DOWN, x_down, reversed(range(m)))):
            for i in order:
                d = 0 if direction == UP else 1
                commanded = home + targets[i]
                out.append(AxisTestMarker(
                    run, axis, i, float(targets[i]), direction, c + 1, float(commanded),
                    float(commanded), float(commanded + x[c, i]),
                    None if true is None else float(commanded + true[d, c, i]), t, t + 0.25,
                    5, 'nominal'))
                t += 1.0
    return out


def test_the_figures_from_markers_are_those_of_iso230_2_on_the_same_numbers() -> None:
    rng = np.random.default_rng(3)
    targets = np.array([-0.001, -0.0004, 0.0002, 0.001])
    up, down = rng.normal(5e-5, 2e-6, (3, 4)), rng.normal(4e-5, 2e-6, (3, 4))
    true = rng.normal(1e-5, 1e-6, (2, 3, 4))
    theta = np.array([-0.01, 0.003, 0.01])
    t_up, t_down = rng.normal(3e-4, 2e-5, (3, 3)), rng.normal(3e-4, 2e-5, (3, 3))
    markers = (_markers_of('leg2_length', targets, up, down, 0.2, true=true)
               + _markers_of('leg1_theta', theta, t_up, t_down, 0.0, t0=1000.0))
    results = axis_test_figures(markers)
    assert results.run == 'r1' and results.notes == ()
    got = {(r.axis, r.source): r for r in results}
    assert set(got) == {('leg2_length', TRACKER), ('leg2_length', TRUTH),
                        ('leg1_theta', TRACKER)}  # no truth in the θ markers
    for (axis, source), p, (xu, xd) in (
            (('leg2_length', TRACKER), targets, (up, down)),
            (('leg2_length', TRUTH), targets, (true[0], true[1])),
            (('leg1_theta', TRACKER), theta, (t_up, t_down))):
        expected = iso230_2(p, p + xu, p + xd)
        f = got[axis, source].figures
        for name in ('targets', 'x_mean_up', 'x_mean_down', 's_up', 'R_i', 'B_i'):
            np.testing.assert_allclose(getattr(f, name), getattr(expected, name), atol=1e-12)
        for name in ('A', 'R', 'B', 'B_mean', 'E', 'E_up', 'M'):
            assert getattr(f, name) == pytest.approx(getattr(expected, name), abs=1e-12)
        assert got[axis, source].cycles == (1, 2, 3)
    doc = json.loads(json.dumps(results.to_dict()))
    assert [r['axis'] for r in doc['results']] == ['leg2_length', 'leg2_length', 'leg1_theta']
    assert doc['results'][0]['unit'] == 'm' and doc['results'][2]['unit'] == 'rad'
    lines = results.markdown()
    assert lines[0].startswith('### leg2_length: tracker (inverse kinematics of the measured '
                               'pose, nominal machine); n = 3, m = 4; deviations in µm, '
                               'targets in mm')
    assert any(line.startswith('### leg2_length: simulation truth') for line in lines)
    assert any('deviations in µrad, targets in mrad' in line for line in lines)
    assert sum(1 for line in lines if line.startswith('| A (')) == 3
    assert len(results.summary()) == 3


def test_the_actuator_uncertainty_is_the_inverse_jacobian_applied_to_the_covariance() -> None:
    """Finite differences of the nominal machine's actuator values against the analytic
    inverse Jacobian (core.kinematics.inverse_jacobian: twist (v, ω in base) to rates): for a
    covariance σ² in one direction of the pose, u = σ·|J[:, d]|; a NaN covariance: NaN."""
    mech = Mechanism.default()
    model = MachineModel(mech)
    p, q = np.array([0.002, -0.001, 0.197]), Rotation.from_rotvec([0.01, -0.02, 0.005]).as_quat()
    jac = inverse_jacobian(mech, p, q)[0]
    for d, sigma in ((0, 3e-6), (2, 5e-6), (3, 2e-5), (5, 1e-5)):
        cov = np.zeros((6, 6))
        cov[d, d] = sigma**2
        np.testing.assert_allclose(actuator_uncertainty(model, p, q, cov),
                                   sigma * np.abs(jac[:, d]), rtol=1e-5, atol=1e-15)
    full = np.diag([9e-12, 9e-12, 16e-12, 1e-10, 1e-10, 4e-10])
    np.testing.assert_allclose(actuator_uncertainty(model, p, q, full),
                               np.sqrt(np.diagonal(jac @ full @ jac.T)), rtol=1e-5)
    assert np.isnan(actuator_uncertainty(model, p, q, np.full((6, 6), math.nan))).all()


def test_incomplete_cycles_and_runs_are_handled_with_a_note() -> None:
    targets = np.array([0.0, 0.001])
    x = np.zeros((3, 2))
    old = _markers_of('leg1_length', targets, x + 1e-5, x, 0.2, run='old')
    new = _markers_of('leg1_length', targets, x, x, 0.2, run='new', t0=100.0)
    del new[5]  # cycle 2 lacks a stop
    results = axis_test_figures(old + new)
    assert results.run == 'new'
    (only,) = results.results
    assert only.cycles == (1, 3)
    assert results.notes == ('leg1_length (tracker): cycle(s) [2] incomplete, left out',)
    assert axis_test_figures(old + new, run='old').results[0].figures.x_mean_up[0] == \
        pytest.approx(1e-5)
    with pytest.raises(InputError, match="no axis-test run 'other'"):
        axis_test_figures(old, run='other')
    two = _markers_of('leg1_length', targets, x[:2], x[:2], 0.2)
    del two[0]
    assert axis_test_figures(two).notes == (
        'leg1_length (tracker): cycle(s) [1] incomplete, left out',
        'leg1_length (tracker): 1 complete cycle(s), ISO 230-2 needs at least 2: no figures')
    assert axis_test_figures([]).notes == ('no axis-test marker',)
    assert axis_test_figures([]).markdown() == ['No axis-test figures.', '',
                                                '- no axis-test marker']


# -- the whole procedure on a simulated machine ---------------------------------------------------
#: Known encoder zero offsets of the simulated machine (real = reading + offset), m and rad.
LENGTH_OFFSETS = (6.0e-5, -9.0e-5, 1.3e-4)
THETA_OFFSETS = (4.0e-4, -2.5e-4, 3.0e-4)


class FaultyPort(InstantPort):
    """The in-process cell, whose jogs can be made to stop half-way with a result code
    (``fail``: jog number from 1 -> code), and which notes where each homing left the axes
    and the mode each jog ran in."""

    fail: dict[int, str]
    homes: list[np.ndarray]
    jog_modes: list[str]

    def jog(self, axis: str, delta: float) -> Moved:
        self.jog_modes.append(self.mode())
        code = self.fail.pop(len(self.jogs) + 1, None)
        if code is None:
            return super().jog(axis, delta)
        super().jog(axis, delta / 2)  # stopped half-way
        moved = Moved(False, code, 'stopped half-way (injected)')
        self.commands[-1] = ('jog', (axis, delta), moved)
        return moved

    def home(self) -> Moved:
        moved = super().home()
        self.homes.append(self.cell.position.copy())
        return moved

    @property
    def jogs(self) -> list[tuple[str, float]]:
        return [cast(tuple[str, float], what) for kind, what, _ in self.commands
                if kind == 'jog']

    @property
    def homed(self) -> int:
        return sum(1 for kind, _, _ in self.commands if kind == 'home')

    @property
    def published(self) -> list[AxisTestMarker]:
        return [AxisTestMarker.from_json(text) for topic, text in self.marks
                if topic == names.AXIS_TEST]


def _port(folder: Path, sim_settings: PoseMeasurementSettings | None = None) -> FaultyPort:
    port = FaultyPort.from_config(folder, sim_settings=sim_settings)
    assert isinstance(port, FaultyPort)
    port.fail, port.homes, port.jog_modes = {}, [], []
    return port


@pytest.fixture
def simulated(tmp_path: Path) -> FaultyPort:
    """The shipped cell with a machine of known zero offsets, in mode none (as the live
    procedure sets it)."""
    sim_settings = parse(PoseMeasurementSettings,
                         node_parameters(load_parameter_file(config_path()), 'pose_measurement'))
    # The machine exactly of the identified model (its effects outside it off): the test
    # claims the zero offsets are seen within a few µm.
    truth = replace(sim_settings.truth.without_effects(), geometry_seed=-1,
                    length_offsets=LENGTH_OFFSETS, theta_offsets=THETA_OFFSETS)
    assert isinstance(truth, TruthParameters)
    port = _port(tmp_path, replace(sim_settings, truth=truth))
    port.set_mode('none')
    return port


SMALL = AxisTest((AxisPlan('leg2_length', (-0.001, -0.0003, 0.0004, 0.001), 0.0003),
                  AxisPlan('leg3_theta', (-0.01, 0.002, 0.01), 0.003)), cycles=3, samples=10,
                 dwell=0.0)


def test_the_procedure_on_a_simulated_machine_shows_its_zero_offsets(
        simulated: FaultyPort) -> None:
    port = simulated
    settings = port.mover.settings
    truth = port.sim.truth
    lines: list[str] = []
    markers = run_procedure(port, SMALL, Reference(truth, 'calibrated'),
                            (settings.operator.jog_largest_length_step,
                             settings.operator.jog_largest_theta_step), lines.append,
                            truth=truth, run='test-run')
    assert markers == port.published and len(markers) == SMALL.measured_stops == 42
    assert len(lines) == 42
    assert lines[0].startswith('[ 1/42] leg2_length cycle 1 ↑ P1 -1.0000 mm:')
    # the stops in the order of the program, each where it was commanded
    measured = [s for s in SMALL.stops() if s.measured]
    assert [(m.axis, m.index, m.direction, m.cycle) for m in markers] == [
        (s.axis, s.index, s.direction, s.cycle) for s in measured]
    # the home values: where the positioner's home move put the axes, in mode none the
    # nominal machine's home (where the program was checked)
    home = port.homes[0]
    np.testing.assert_allclose(home, home_joints(settings.mechanism), atol=1e-12)
    for m in markers:
        k = JOINT_NAMES.index(m.axis)
        assert m.commanded == pytest.approx(home[k] + m.target, abs=1e-12)
        assert m.encoder == pytest.approx(m.commanded, abs=1e-12)
        assert m.reference == 'calibrated' and m.run == 'test-run' and m.samples == 10
        assert m.tracker_u is not None and m.tracker_u > 0.0
    # homed before and after; the axes went back to their home values before that
    assert port.homed == 2
    back = [j for j in port.jogs if j[0] == 'leg2_length']
    assert sum(d for _, d in back) == pytest.approx(0.0, abs=1e-12)
    results = axis_test_figures(markers)
    assert results.notes == ()
    got = {(r.axis, r.source): r.figures for r in results}
    offsets = np.r_[LENGTH_OFFSETS, THETA_OFFSETS]
    for axis in ('leg2_length', 'leg3_theta'):
        k = JOINT_NAMES.index(axis)
        by_truth = got[axis, TRUTH]
        # the truth: every mean deviation is the axis's zero offset, nothing else (the drives
        # stand exactly where commanded)
        np.testing.assert_allclose(by_truth.x_mean_up, offsets[k], atol=1e-12)
        np.testing.assert_allclose(by_truth.x_mean_down, offsets[k], atol=1e-12)
        assert by_truth.R < 1e-12 and by_truth.E < 1e-12
        # the tracker through the true machine (a perfect calibration): the offset within the
        # tracker's noise (registration common to all stops included)
        tracker = got[axis, TRACKER]
        noise = 5e-6 if k < 3 else 6e-5
        assert abs(float(np.mean(tracker.x_mean)) - offsets[k]) < noise
        assert tracker.R > 0.0
        # each axis figure from the tracker within its U of the truth's (measurement only:
        # the reference is the true machine)
        u = results.by_axis()[axis][TRACKER].uncertainty
        assert u is not None and results.by_axis()[axis][TRUTH].uncertainty is None
        for name in ('A', 'A_up', 'A_down', 'R', 'R_up', 'R_down', 'B', 'B_mean', 'E',
                     'E_up', 'E_down', 'M'):
            assert abs(getattr(tracker, name) - getattr(by_truth, name)) <= u[name], name
    # the tracker through the nominal machine sees the geometry too: not the offset
    port.marks.clear()
    nominal = run_procedure(port, SMALL, Reference(MachineModel(settings.mechanism), 'nominal'),
                            (0.005, 0.05), lines.append, truth=truth)
    tracker = axis_test_figures(nominal).by_axis()['leg2_length'][TRACKER].figures
    assert abs(float(np.mean(tracker.x_mean)) - offsets[1]) > 2e-5


def test_a_transient_abort_is_tried_again_and_any_other_ends_the_test(
        simulated: FaultyPort) -> None:
    port = simulated
    truth = port.sim.truth
    test = AxisTest((AxisPlan('leg1_length', (-0.001, 0.0005, 0.001), 0.0003),), cycles=2,
                     samples=3, dwell=0.0)
    lines: list[str] = []
    port.fail = {3: 'aborted_driver_lost'}  # the approach up to P_2 of cycle 1, half-way
    markers = run_procedure(port, test, Reference(truth, 'calibrated'), (0.005, 0.05),
                            lines.append, truth=truth)
    assert [line for line in lines if 'trying again' in line] == [
        'leg1_length: jog leg1_length by +0.0015: aborted_driver_lost: stopped half-way '
        '(injected); trying again (1/3)']
    assert len(markers) == 12
    figures = axis_test_figures(markers).by_axis()['leg1_length'][TRUTH].figures
    np.testing.assert_allclose(figures.x_mean, LENGTH_OFFSETS[0], atol=1e-12)
    port.fail = {len(port.jogs) + 4: 'aborted_fault'}
    homed = port.homed
    with pytest.raises(ProcedureError, match='aborted_fault') as failed:
        run_procedure(port, test, Reference(truth, 'calibrated'), (0.005, 0.05), lines.append)
    assert failed.value.code == 'aborted_fault'
    assert port.homed == homed + 2  # at the start, and after the failure


def test_a_long_move_is_split_into_jogs_within_the_largest_step(simulated: FaultyPort) -> None:
    port = simulated
    test = AxisTest((AxisPlan('leg1_theta', (-0.02, 0.0, 0.02), 0.005),), cycles=2, samples=2,
                     dwell=0.0)
    run_procedure(port, test, Reference(port.sim.truth, 'calibrated'), (0.005, 0.006),
                  lambda s: None)
    steps = [abs(d) for _, d in port.jogs]
    assert max(steps) <= 0.006 + 1e-12
    assert len(steps) > len(test.stops())  # 25 mrad moves in 5 jogs of 5 mrad


TINY = AxisTest((AxisPlan('leg3_length', (-0.0005, 0.0005), 0.0002),), cycles=2, samples=4,
                dwell=0.1)


def test_the_run_sets_mode_none_puts_it_back_and_judges_by_the_configs_truth(
        tmp_path: Path) -> None:
    """run_axis_test on the shipped cell: mode none while it runs, the positioner's machine
    (nominal, no calibration loaded), the truth read from the parameter file only, the tables
    written."""
    port = _port(tmp_path)
    assert port.mode() == 'measured'
    lines: list[str] = []
    run = run_axis_test(port, TINY, config_path(), lines.append)
    assert port.mode() == 'measured' and set(port.jog_modes) == {'none'}
    assert lines[0] == ('axis test (ISO 230-2): 1 axis, 8 measured stops (2 cycles), 4 tracker '
                        'readings each; actual positions from the tracker through the nominal '
                        'machine and from the simulation truth; about '
                        f'{lines[0].split("about ")[1]}')
    assert lines[-1] == 'no recorder took the markers (/cell/axis_test): not in a bag'
    assert run.markers == port.published and len(run.markers) == 8
    assert {m.reference for m in run.markers} == {'nominal'}
    # the truth of config/cell.yaml (the same machine the port simulates): the zero offset
    truth = simulation_truth(config_path())
    assert truth is not None
    figures = run.results.by_axis()['leg3_length'][TRUTH].figures
    np.testing.assert_allclose(figures.x_mean, truth.length_offsets[2], atol=1e-12)
    # without judging: no truth in the markers
    port.marks.clear()
    unjudged = run_axis_test(port, TINY, config_path(), lines.append, judge=False)
    assert all(m.true is None for m in unjudged.markers)
    assert [r.source for r in unjudged.results] == [TRACKER]
    md, js = write(run.results, tmp_path / 'out')
    assert json.loads(js.read_text()) == json.loads(json.dumps(run.results.to_dict()))
    assert md.read_text().startswith('# Axis test (ISO 230-2:2014)\n\n### leg3_length')


def test_the_run_measures_through_the_loaded_calibration(tmp_path: Path) -> None:
    """With a calibration file loaded, the measured values go through the calibrated
    machine; here the truth itself written as a calibration file, so the tracker sees the
    zero offset. The machine is exactly of the identified model (its effects outside it
    off), so the truth written as a calibration is exact."""
    sim_settings = simulator(config_path())
    assert sim_settings is not None
    sim_settings = replace(sim_settings, truth=sim_settings.truth.without_effects())
    port = _port(tmp_path, sim_settings)
    settings = machine_settings(config_path())
    truth = sim_settings.true_machine()
    path = exact_calibration(truth, settings.mechanism, tmp_path / 'calibration.yaml')

    def tracker_offset() -> tuple[str, float]:
        """The reference machine named in the markers; the tracker's mean deviation from
        the truth's zero offset."""
        run = run_axis_test(port, TINY, config_path(), lambda s: None)
        port.marks.clear()
        (reference,) = {m.reference for m in run.markers}
        figures = run.results.by_axis()['leg3_length'][TRACKER].figures
        return reference, float(np.mean(figures.x_mean)) - truth.length_offsets[2]

    reference, off = tracker_offset()
    assert reference == 'nominal' and abs(off) > 2e-5  # the nominal machine: its geometry too
    taken, reason = port.load_calibration(str(path))
    assert taken, reason
    assert port.calibration_file() == str(path)
    reference, off = tracker_offset()
    assert reference == 'calibrated' and abs(off) < 5e-6


def test_a_refused_mode_starts_nothing_and_an_interrupt_stops_the_drives(
        tmp_path: Path) -> None:
    port = _port(tmp_path)

    def refuse(mode: str) -> None:
        raise ProcedureError(f'the positioner refused compensation.mode = {mode}: busy')

    port.set_mode = refuse  # type: ignore[method-assign]
    with pytest.raises(ModeRefusedError, match=r'refused compensation\.mode = none: busy'):
        run_axis_test(port, TINY, config_path(), lambda s: None)
    assert port.commands == [] and port.marks == []

    port = _port(tmp_path)

    def interrupted(axis: str, delta: float) -> Moved:
        raise Interrupted('SIGINT')

    port.jog = interrupted  # type: ignore[method-assign]
    with pytest.raises(Interrupted):
        run_axis_test(port, TINY, config_path(), lambda s: None)
    assert port.stops == 1 and port.mode() == 'measured'
