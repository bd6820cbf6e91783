"""The simulated machine's effects outside the identified model (positioning_cell.sim.effects):
each effect's size against a hand computation or a second path (the exact machine fed the
hand-corrected joints, the statics' first-order deflection), the reversal following the
approach, the legs' heating, the all-off machine being today's, seeds, refusals, the air
temperature sensor and the tracker's refraction, and the offline campaign's conditions."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanics.statics import deflection
from positioning_cell.parameters import parse
from positioning_cell.sim.campaign import Timing, measure_program
from positioning_cell.sim.effects.history import (
    Conditions,
    MachineHistory,
    approach_directions,
    sequence_conditions,
)
from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE, ThermalParameters
from positioning_cell.sim.encoders import EncoderSettings
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator
from positioning_cell.sim.truth import Truth, TruthParameters, settled, truth_from_params

SETTINGS = parse(PoseMeasurementSettings,
                 node_parameters(load_parameter_file(config_path()), 'pose_measurement'))
MECH, PAYLOAD, STRUCTURE = SETTINGS.mechanism, SETTINGS.payload, SETTINGS.structure
TRUTH = SETTINGS.truth
OFF = TRUTH.without_effects()
#: Three poses spread over the workspace (position m, rotation small).
POSITIONS = MECH.home_position + np.array([[0.0, 0.0, 0.0], [0.01, -0.005, 0.008],
                                           [-0.008, 0.01, -0.01]])
QUATERNIONS = np.array([[0.0, 0.0, 0.0, 1.0], [0.02, -0.01, 0.03, 0.99925],
                        [-0.03, 0.02, -0.01, 0.99935]])
QUATERNIONS /= np.linalg.norm(QUATERNIONS, axis=1, keepdims=True)
CMD = inverse(MECH, POSITIONS, QUATERNIONS)
N = len(POSITIONS)


def machine(params: TruthParameters, payload: Any = PAYLOAD) -> Truth:
    return Truth.from_parameters(params, MECH, payload, STRUCTURE)


def only(**groups: Any) -> TruthParameters:
    """The config's machine with only the given effect groups (enabled) and no clearance, so
    a hand computation sees each effect alone."""
    base = replace(OFF, clearance=replace(OFF.clearance, model='none'))
    return replace(base, **{k: replace(getattr(base, k), enabled=True, **v)
                            for k, v in groups.items()})


def exact(params: TruthParameters) -> Truth:
    return machine(params.without_effects())


NO_DRIVE = dict(lead_error_sigma=0.0, periodic_amplitude=0.0, length_reversal=(0.0, 0.0),
                theta_scale_sigma=0.0, theta_reversal=(0.0, 0.0))


def test_the_shipped_config_switches_every_effect_on() -> None:
    assert TRUTH.drives.enabled and TRUTH.thermal.enabled and TRUTH.compliance.enabled
    fx = SETTINGS.true_machine().effects
    assert fx.active and None not in (fx.drives, fx.thermal, fx.compliance)
    assert not machine(OFF).effects.active
    # The truth's stiffnesses are its own, not the cell's nominal structure.
    assert TRUTH.compliance.leg_stiffness != STRUCTURE.leg_stiffness
    assert TRUTH.compliance.theta_stiffness != STRUCTURE.theta_stiffness


def test_all_effects_off_are_the_exact_machine_of_today() -> None:
    """Effects switched on with zero sizes (fixed-point path) against the machine without
    effects (MachineModel.poses): the same poses, within what the fixed point's tolerance on
    the joint shift (1e-11 m, rad) leaves: a leg's length off by that turns the 0.1 m platform
    by up to 1e-10 rad."""
    params = replace(OFF, drives=replace(OFF.drives, enabled=True, **NO_DRIVE),
                     thermal=replace(OFF.thermal, enabled=True, air_start=20.0,
                                     air_drift=0.0, air_noise=0.0),
                     compliance=replace(OFF.compliance, enabled=True, leg_stiffness=1e30,
                                        theta_stiffness=1e30, u_radial_stiffness=1e30,
                                        s_radial_stiffness=1e30))
    zero = machine(params)
    assert zero.effects.active
    got = zero.poses(CMD.lengths, CMD.thetas, conditions=Conditions.reference(N))
    want = machine(OFF).poses(CMD.lengths, CMD.thetas)
    np.testing.assert_allclose(got.position, want.position, atol=1e-12, rtol=0.0)
    np.testing.assert_allclose(got.quaternion, want.quaternion, atol=1e-10, rtol=0.0)


def test_lead_and_periodic_errors_are_those_of_the_screw() -> None:
    """l_real = l + s (l − l_ref) + a sin(2π (l − l_ref)/p + φ) by hand, fed to the exact
    machine."""
    params = only(drives={**NO_DRIVE, 'lead_error_sigma': 30.0, 'periodic_amplitude': 2e-6})
    truth = machine(params)
    d = truth.effects.drives
    assert d is not None and np.all(np.abs(d.lead_scale) > 0.0)
    real = CMD.lengths + truth.length_offsets
    travel = real - MECH.home_length
    hand = real + d.lead_scale * travel + 2e-6 * np.sin(2 * np.pi * travel / 0.005 + d.phase)
    want = exact(params).poses(hand - truth.length_offsets, CMD.thetas)
    got = truth.poses(CMD.lengths, CMD.thetas)
    np.testing.assert_allclose(got.position, want.position, atol=1e-12, rtol=0.0)
    assert np.max(np.abs(hand - real)) > 1e-7  # the error is there to see


def test_reversal_follows_the_approach_and_flips_with_it() -> None:
    params = only(drives={**NO_DRIVE, 'length_reversal': (3e-6, 8e-6),
                          'theta_reversal': (1e-5, 3e-5)})
    truth = machine(params)
    d = truth.effects.drives
    assert d is not None and np.all((d.length_band >= 3e-6) & (d.length_band <= 8e-6))
    up = Conditions.reference(N)._replace(approach=np.ones((N, 6)))
    down = up._replace(approach=-np.ones((N, 6)))
    from_up = truth.poses(CMD.lengths, CMD.thetas, conditions=up)
    from_down = truth.poses(CMD.lengths, CMD.thetas, conditions=down)
    lagging = exact(params).poses(CMD.lengths - d.length_band / 2,
                                  CMD.thetas - d.theta_band / 2)
    leading = exact(params).poses(CMD.lengths + d.length_band / 2,
                                  CMD.thetas + d.theta_band / 2)
    np.testing.assert_allclose(from_up.position, lagging.position, atol=1e-12, rtol=0.0)
    np.testing.assert_allclose(from_down.position, leading.position, atol=1e-12, rtol=0.0)
    unknown = truth.poses(CMD.lengths, CMD.thetas)  # approach 0: the middle of the band
    np.testing.assert_allclose(unknown.position, exact(params).poses(CMD.lengths,
                                                                     CMD.thetas).position,
                               atol=1e-12, rtol=0.0)
    gap = np.linalg.norm(from_up.position - from_down.position, axis=1)
    assert np.all(gap > 1e-6) and np.all(gap < 1e-4)


def test_thermal_expansion_of_legs_and_joint_circles() -> None:
    """Legs longer by α_l·l·ΔT and joint circles larger by α·ΔT: the exact machine with the
    hand-expanded lengths and joint centres."""
    params = only(thermal={})
    truth = machine(params)
    air, leg = 23.0, np.array([24.0, 25.0, 26.5])
    cond = Conditions(np.full(N, air), np.tile(leg, (N, 1)), np.zeros((N, 6)))
    got = truth.poses(CMD.lengths, CMD.thetas, conditions=cond)
    th = params.thermal
    real = (CMD.lengths + truth.length_offsets) * (1 + th.leg_expansion * (leg - 20.0))
    mech = truth.mechanism
    grown = mech.with_offsets(
        np.asarray(mech.base_offsets) + th.base_expansion * 3.0 * mech.base_joints,
        np.asarray(mech.platform_offsets) + th.platform_expansion * 3.0 * mech.platform_joints)
    want = Truth(grown, None, truth.length_offsets, truth.theta_offsets).poses(
        real - truth.length_offsets, CMD.thetas)
    np.testing.assert_allclose(got.position, want.position, atol=1e-11, rtol=0.0)
    shift = np.linalg.norm(got.position - truth.poses(CMD.lengths, CMD.thetas).position, axis=1)
    assert np.all(shift > 11.5e-6 * 0.2 * 3.0)  # at least one leg's growth, order µm
    assert np.all(shift < 1e-4)


def test_compliance_is_the_statics_deflection_at_the_truths_stiffness() -> None:
    """Legs and θ drives only (joints radially rigid): the pose change against the statics'
    first-order deflection δx = −C·w (seed 002 eq. 28) with the truth's stiffnesses."""
    params = only(compliance={'u_radial_stiffness': 1e30, 's_radial_stiffness': 1e30})
    truth = machine(params)
    rigid = exact(params).poses(CMD.lengths, CMD.thetas)
    got = truth.poses(CMD.lengths, CMD.thetas)
    c = params.compliance
    stiff = replace(STRUCTURE, leg_stiffness=c.leg_stiffness, theta_stiffness=c.theta_stiffness)
    want = deflection(truth.mechanism, rigid.position, rigid.quaternion, PAYLOAD, stiff)
    moved = got.position - rigid.position
    np.testing.assert_allclose(moved, want.translation, rtol=0.03, atol=1e-6)
    # More payload, more deflection: the load comes from the statics.
    heavy = machine(params, replace(PAYLOAD, mass=80.0)).poses(CMD.lengths, CMD.thetas)
    assert np.all(np.linalg.norm(heavy.position - rigid.position, axis=1)
                  > np.linalg.norm(moved, axis=1))


def test_radial_joint_compliance_is_linear_in_its_compliance() -> None:
    params = only(compliance={'leg_stiffness': 1e30, 'theta_stiffness': 1e30})
    rigid = exact(params).poses(CMD.lengths, CMD.thetas).position
    soft = machine(params).poses(CMD.lengths, CMD.thetas).position - rigid
    c = params.compliance
    stiffer = replace(params, compliance=replace(c, u_radial_stiffness=2 * c.u_radial_stiffness,
                                                 s_radial_stiffness=2 * c.s_radial_stiffness))
    half = machine(stiffer).poses(CMD.lengths, CMD.thetas).position - rigid
    assert np.all(np.linalg.norm(soft, axis=1) > 5e-7)
    np.testing.assert_allclose(half, soft / 2, atol=2e-8, rtol=0.0)


def test_approach_is_the_sign_of_each_axis_last_change() -> None:
    cmd = np.array([[0.0] * 6, [1.0] + [0.0] * 5, [1.0, 2.0] + [0.0] * 4,
                    [0.5, 2.0] + [0.0] * 4, [0.5, 1.0] + [0.0] * 4])
    got = approach_directions(cmd)
    np.testing.assert_array_equal(got[:, :2], [[0, 0], [1, 0], [1, 1], [-1, 1], [-1, -1]])
    assert not np.any(got[:, 2:])


def test_legs_warm_with_travel_and_cool_with_the_time_constant() -> None:
    th = replace(ThermalParameters(), enabled=True, air_noise=0.0, air_drift=0.0).draw()
    tau, h = th.parameters.time_constant, th.parameters.leg_heating
    cmd = np.zeros((4, 6))
    cmd[1:, 0] = 0.02  # leg 1 travels 20 mm before the second pose, then stands
    times = np.array([0.0, 10.0, 10.0 + tau, 10.0 + 3 * tau])
    cond = sequence_conditions(th, cmd, times)
    excess = cond.legs[:, 0] - cond.air
    np.testing.assert_allclose(excess, [0.0, h * 0.02, h * 0.02 / np.e, h * 0.02 / np.e**3],
                               rtol=1e-12, atol=1e-15)
    assert not np.any(cond.legs[:, 1:] - cond.air[:, None])
    # Second path: the stream history of the same motion gives the same temperatures.
    history = MachineHistory(th)
    for row, t in zip(cmd, times, strict=True):
        history.update(row, t)
        np.testing.assert_allclose(history.conditions(t).legs[0],
                                   cond.legs[list(times).index(t)], rtol=1e-12)


def test_stream_history_turns_only_beyond_the_dither() -> None:
    history = MachineHistory(None)
    path = [0.0, 1e-5, 2e-5, 2e-5 - 5e-8, 1e-5]  # up, a dither back, then down
    seen = []
    for k, x in enumerate(path):
        history.update(np.full(6, x), float(k))
        seen.append(history.conditions(float(k)).approach[0, 0])
    assert seen == [0.0, 1.0, 1.0, 1.0, -1.0]


def test_the_reversal_band_is_a_play_that_servo_dither_does_not_cross() -> None:
    band = 6e-6
    history = MachineHistory(None, np.r_[[band] * 3, [2e-5] * 3])
    real = []
    # up 20 um (play taken up: +1), dither of 0.3 um, back 2 um (inside the play: the axis
    # stays), back 10 um more (the play taken up the other way: -1)
    for k, x in enumerate([0.0, 2e-5, 2e-5 - 3e-7, 2e-5, 1.8e-5, 0.8e-5]):
        history.update(np.full(6, x), float(k))
        a = history.conditions(float(k)).approach[0, 0]
        real.append(x - 0.5 * a * band)
    np.testing.assert_allclose(real[1:4], [2e-5 - band / 2] * 3, rtol=0, atol=1e-15)
    np.testing.assert_allclose(real[4], 2e-5 - band / 2, rtol=0, atol=1e-15)
    assert history.conditions(5.0).approach[0, 0] == pytest.approx(-1.0)
    np.testing.assert_allclose(real[5], 0.8e-5 + band / 2, rtol=0, atol=1e-15)


def test_seeds_make_different_machines_and_the_same_seed_the_same() -> None:
    a = machine(TRUTH).effects
    b = machine(TRUTH).effects
    c = machine(replace(TRUTH, drives=replace(TRUTH.drives, seed=7),
                        thermal=replace(TRUTH.thermal, seed=7))).effects
    assert a.drives is not None and b.drives is not None and c.drives is not None
    assert a.thermal is not None and b.thermal is not None and c.thermal is not None
    np.testing.assert_array_equal(a.drives.lead_scale, b.drives.lead_scale)
    assert a.thermal.sensor_offset == b.thermal.sensor_offset
    assert not np.allclose(a.drives.lead_scale, c.drives.lead_scale)
    assert a.thermal.sensor_offset != c.thermal.sensor_offset
    assert not np.allclose(a.thermal.air(np.arange(0, 7200, 600.0)),
                           c.thermal.air(np.arange(0, 7200, 600.0)))


@pytest.mark.parametrize('key, value', [
    ('drives.length_reversal', [8e-6, 3e-6]),
    ('drives.screw_pitch', 0.0),
    ('thermal.time_constant', 0.0),
    ('thermal.noise_periods', [7200.0, 600.0]),
    ('compliance.leg_stiffness', -1.0),
    ('compliance.enabled', 'yes'),
])
def test_bad_effect_parameters_are_refused_naming_the_key(key: str, value: Any) -> None:
    with pytest.raises(ConfigError, match=f'truth.{key}'):
        truth_from_params({key: value}, MECH)


def test_air_temperature_readings_carry_the_sensors_error() -> None:
    sim = PoseMeasurementSimulator(SETTINGS)
    th = sim.truth.effects.thermal
    assert th is not None
    times = np.arange(0.0, 4 * 3600.0, 60.0)
    readings = np.array([sim.air_temperature(t) for t in times])
    air = th.air(times)
    p = SETTINGS.truth.thermal
    np.testing.assert_allclose(readings[:, 1], p.sensor_offset_sigma**2 + p.sensor_noise**2)
    error = readings[:, 0] - air
    assert abs(error.mean() - th.sensor_offset) < 4 * p.sensor_noise / np.sqrt(len(times))
    assert 0.5 * p.sensor_noise < error.std() < 1.5 * p.sensor_noise
    assert air[-1] - air[0] == pytest.approx(p.air_drift * 4, abs=4 * p.air_noise)
    cold = PoseMeasurementSimulator(replace(SETTINGS, truth=SETTINGS.truth.without_effects()))
    assert cold.air_temperature(100.0).temperature == REFERENCE_TEMPERATURE


def test_the_tracker_range_scales_with_the_air_temperature_error() -> None:
    sim = PoseMeasurementSimulator(SETTINGS)
    points = np.array([[0.1, 0.0, 0.3], [-0.2, 0.1, 0.2]])
    plain = sim.instrument.read(points, np.random.default_rng(4))
    warm = sim.instrument.read(points, np.random.default_rng(4), refraction_ppm=-0.95 * 2.0)
    true_ranges = sim.instrument.placed.spherical(points)[:, 0]
    np.testing.assert_allclose(np.linalg.norm(warm.local, axis=1)
                               - np.linalg.norm(plain.local, axis=1),
                               true_ranges * -1.9e-6, rtol=1e-6, atol=1e-14)


def test_the_campaign_records_the_sensors_temperature_and_the_approach() -> None:
    sim = PoseMeasurementSimulator(SETTINGS)
    assert sim.location is not None
    cmd = np.c_[CMD.lengths, CMD.thetas][[0, 1, 2, 1]]
    timing = Timing(seconds_per_pose=600.0)
    data = measure_program(sim.truth, sim.instrument, sim.location.tracker, SETTINGS.targets,
                           EncoderSettings(), cmd, np.random.default_rng(2), samples=3,
                           timing=timing)
    assert data.approach is not None and data.temperature is not None
    np.testing.assert_array_equal(data.approach, approach_directions(cmd))
    th = sim.truth.effects.thermal
    assert th is not None
    air = th.air(timing.times(4))
    assert np.all(np.abs(data.temperature - air - th.sensor_offset)
                  < 5 * SETTINGS.truth.thermal.sensor_noise)
    exact_sim = PoseMeasurementSimulator(replace(SETTINGS,
                                                 truth=SETTINGS.truth.without_effects()))
    assert exact_sim.location is not None
    plain = measure_program(exact_sim.truth, exact_sim.instrument, exact_sim.location.tracker,
                            SETTINGS.targets, EncoderSettings(), cmd, np.random.default_rng(2),
                            samples=3)
    assert plain.temperature is not None
    np.testing.assert_array_equal(plain.temperature, REFERENCE_TEMPERATURE)


def test_the_simulators_true_pose_follows_the_approach() -> None:
    """The pose_measurement simulator fed a leg that comes to the same joints from above and
    from below: the true poses differ by the reversal band (drives only)."""
    params = replace(SETTINGS.truth.without_effects(),
                     drives=replace(SETTINGS.truth.drives, enabled=True))
    sim = PoseMeasurementSimulator(replace(SETTINGS, truth=params))
    home = np.r_[CMD.lengths[0], CMD.thetas[0]]
    poses = []
    for k, step in enumerate([-1e-4, 0.0, 1e-4, 0.0]):
        sim.joints(home + step, k, float(k))
        true = sim.update_truth()
        assert true is not None
        poses.append(true.position)
    d = sim.truth.effects.drives
    assert d is not None
    moved = np.linalg.norm(poses[1] - poses[3])
    assert moved > 0.5 * d.length_band.min()


def test_the_fixed_point_solves_the_machine_and_a_too_soft_one_has_no_pose() -> None:
    """The pose of the full machine (every effect on) satisfies IK(x) + shift(x) = the real
    joints it was commanded to; a θ drive too soft to hold the payload gives no pose."""
    truth = SETTINGS.true_machine()
    cond = Conditions(np.full(N, 22.0), np.full((N, 3), 23.0),
                      np.array([[1.0, -1.0, 1.0, -1.0, 1.0, 1.0]] * N))
    got = truth.poses(CMD.lengths, CMD.thetas, conditions=cond)
    assert np.all(got.converged)
    fx = truth.effects
    assert fx.drives is not None and fx.thermal is not None
    real_l, real_t = fx.drives.actual(CMD.lengths + truth.length_offsets,
                                      CMD.thetas + truth.theta_offsets, cond.approach)
    real_l = fx.thermal.expanded_lengths(real_l, cond.legs)
    needed = inverse(truth.mechanism, got.position, got.quaternion)
    shift = truth.joint_shift(got.position, got.quaternion, cond.air)
    np.testing.assert_allclose(needed.lengths + shift[:, :3], real_l, atol=1e-11, rtol=0.0)
    np.testing.assert_allclose(needed.thetas + shift[:, 3:], real_t, atol=1e-10, rtol=0.0)
    soft = machine(only(compliance={'theta_stiffness': 100.0}))
    assert not np.any(soft.poses(CMD.lengths, CMD.thetas).converged)


def test_a_fixed_point_started_from_a_nearby_shift_settles_on_the_same_pose() -> None:
    """Truth.settle started from the shift of a pose 0.2 mm away (the simulator's stream: the
    previous true pose's) gives the pose a start from zero gives, within the fixed point's
    tolerance; the shift it returns is the one the cold start settles on; a shift that is not
    finite is refused."""
    truth = machine(TRUTH)
    near = inverse(MECH, POSITIONS + 2e-4, QUATERNIONS)
    _, start = truth.settle(near.lengths, near.thetas)
    cold, cold_shift = truth.settle(CMD.lengths, CMD.thetas)
    warm, warm_shift = truth.settle(CMD.lengths, CMD.thetas, shift0=start)
    assert np.max(np.abs(start - cold_shift)) > 1e-9  # a real change of the effects
    np.testing.assert_allclose(warm.position, cold.position, rtol=0, atol=1e-11)
    np.testing.assert_allclose(warm.quaternion, cold.quaternion, rtol=0, atol=1e-11)
    np.testing.assert_allclose(warm_shift, cold_shift, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(truth.poses(CMD.lengths, CMD.thetas).position, cold.position)
    with pytest.raises(InputError, match='shift0'):
        truth.settle(CMD.lengths, CMD.thetas, shift0=np.full(6, np.nan))
    exact_shift = exact(TRUTH).settle(CMD.lengths, CMD.thetas)[1]
    assert exact_shift.shape == (N, 6) and not exact_shift.any()


def test_the_simulators_stream_starts_each_fixed_point_from_the_shifts_trend(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The pose_measurement simulator fed a move's joint stream (every effect on, 50 updates):
    each true pose is the one a start from zero gives (within the fixed point's tolerance), and
    starting from the previous shifts' trend takes about two rounds an update, the second
    vouching for the shift through the contraction's rate (three waiting for the change itself
    to fall below the tolerance, four from the previous shift alone, five from zero)."""
    sim = PoseMeasurementSimulator(SETTINGS)
    steps = np.linspace(0.0, 1.0, 51)[:, None]
    moved = inverse(MECH, MECH.home_position + steps * np.array([0.004, 0.003, -0.002]),
                    np.tile(QUATERNIONS[0], (len(steps), 1)))
    joints = np.c_[moved.lengths, moved.thetas]
    rounds = [0]
    shift = Truth.joint_shift

    def counted(self: Truth, *args: Any) -> Any:
        rounds[0] += 1
        return shift(self, *args)

    for k, values in enumerate(joints):
        sim.joints(values, k, 0.02 * k)
        if k == 1:
            monkeypatch.setattr(Truth, 'joint_shift', counted)
        true = sim.update_truth()
        assert true is not None
        if k % 10 == 5:
            with monkeypatch.context() as m:
                m.setattr(Truth, 'joint_shift', shift)
                cold = sim.truth.poses(values[None, :3], values[None, 3:], None,
                                       sim.history.conditions(0.02 * k))
            np.testing.assert_allclose(true.position, cold.position[0], rtol=0, atol=1e-11)
            np.testing.assert_allclose(true.quaternion, cold.quaternion[0], rtol=0, atol=1e-11)
    assert rounds[0] <= 2.3 * (len(joints) - 1), rounds[0] / (len(joints) - 1)


def test_the_compliance_and_a_load_driven_clearance_share_one_statics_a_pose(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Truth.joint_shift with the shipped machine (load-driven clearance, compliance on): the
    statics (actuator efforts, joint forces) once a call, and the shift it gives is the one
    computing them for each effect apart gives; a clearance of another payload computes its
    own."""
    from positioning_cell.clearance.load import LoadAwareClearance
    from positioning_cell.mechanics import statics
    from positioning_cell.sim import truth as truth_module

    truth = SETTINGS.true_machine()
    assert isinstance(truth.clearance, LoadAwareClearance) and truth.effects.compliance
    air = np.full(N, 21.0)
    calls = {'actuator_efforts': 0, 'joint_forces': 0}

    def counting(name: str) -> Any:
        function = getattr(statics, name)

        def counted(*args: Any, **kwargs: Any) -> Any:
            calls[name] += 1
            return function(*args, **kwargs)
        return counted

    for name in calls:
        counted = counting(name)  # one wrapper of the function, wherever it is imported
        for module in ('positioning_cell.mechanics.statics', 'positioning_cell.clearance.load',
                       'positioning_cell.sim.effects.compliance'):
            monkeypatch.setattr(f'{module}.{name}', counted, raising=False)
    shared = truth.joint_shift(POSITIONS, QUATERNIONS, air)
    assert calls == {'actuator_efforts': 1, 'joint_forces': 1}, calls
    monkeypatch.undo()
    # each effect its own statics: the clearance not recognised as load-driven
    monkeypatch.setattr(truth_module, 'LoadAwareClearance', type('Other', (), {}))
    apart = truth.joint_shift(POSITIONS, QUATERNIONS, air)
    np.testing.assert_allclose(shared, apart, rtol=0.0, atol=1e-15)
    assert np.max(np.abs(shared)) > 1e-6  # a real shift
    # a clearance loaded by another payload than the compliance's: its own statics
    monkeypatch.undo()
    other = replace(truth, clearance=replace(truth.clearance,
                                             payload=replace(PAYLOAD, mass=PAYLOAD.mass * 2)))
    assert np.max(np.abs(other.joint_shift(POSITIONS, QUATERNIONS, air) - shared)) > 1e-7


@pytest.mark.parametrize(('changes', 'settles_at'), [
    ([1e-8, 1e-10], 1),  # rate 1e-2: 1e-12 left after the second round
    ([1e-8, 5e-10, 2.5e-11], 2),  # rate 5e-2: 1.3e-12 left after the third, 2.6e-11 before
    ([3e-9, 2.7e-9, 2.43e-9, 2.187e-9], None),  # rate 0.9: nine times the change left
    ([1e-9, 2e-9], None),  # growing: not a contraction
    ([5e-12], 0),  # the change itself within the tolerance
])
def test_a_fixed_point_stops_once_its_rate_vouches_for_the_tolerance(
        changes: list[float], settles_at: int | None) -> None:
    """truth.settled (tolerance 1e-11): a first round only by its change, later ones by the
    error the rate of the last two changes leaves."""
    previous, stops = math.inf, []
    for change in changes:
        stops.append(settled(change, previous, 1e-11))
        previous = change
    assert (stops.index(True) if any(stops) else None) == settles_at, stops
    assert not settled(1e-9, 0.0, 1e-11)  # no rate from a change of 0 (nor a division by it)
