"""Live compensation under measured conditions (positioning_cell.motion.compensation and the
mover): the calibrated machine's thermal terms follow the measured air temperature, its
reversal terms the direction each axis moves in, and a move outside the calibration's
envelope or on a stale temperature says so without being refused. No DDS: the mover over the
instant cell (sim/instant_cell.py)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.calibrated import Calibrated
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.envelope import envelope_of
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.motion.compensation import Compensation
from positioning_cell.motion.mover import Mover
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.motion.temperature import TemperatureSettings
from positioning_cell.parameters import parse
from positioning_cell.sim.instant_cell import DRIVES_READY, InstantCell
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator

CONFIG = load_parameter_file(config_path())
SETTINGS = parse(PositionerSettings, node_parameters(CONFIG, 'positioner'))
MECH, PAYLOAD, STRUCTURE = SETTINGS.mechanism, SETTINGS.payload, SETTINGS.structure
HOME_P, HOME_Q = np.asarray(MECH.home_position, float), np.asarray(MECH.home_quaternion, float)
TEMPERATURE = TemperatureSettings(max_age=10.0, nominal=20.0, nominal_sigma=3.0,
                                  sensor_sigma=0.1, drift_rate=0.01)


def calibrated(expansion: float = 2e-5, reversal: float = 5e-6, envelope: Any = None
               ) -> Calibrated:
    """A calibrated machine: the nominal geometry with thermal and reversal terms only."""
    x = np.zeros(cp.COUNT)
    x[cp.LEG_EXPANSION] = expansion
    x[cp.REVERSAL] = np.r_[[reversal] * 3, [10 * reversal] * 3]
    return Calibrated(cp.machine_model(x, MECH, PAYLOAD, STRUCTURE, reference_temperature=20.0),
                      envelope, ())


def joints_of(result: Any) -> Any:
    return np.concatenate([result.lengths[0], result.thetas[0]])


def test_the_thermal_terms_follow_the_measured_temperature() -> None:
    machine = calibrated()
    compensation = Compensation(TEMPERATURE)
    at_nominal = joints_of(compensation.model(machine, 0.0).compensate(MECH, HOME_P, HOME_Q))
    compensation.temperature.update(25.0, 0.01, now=1.0)
    warm = joints_of(compensation.model(machine, 1.0).compensate(MECH, HOME_P, HOME_Q))
    # the same as the model's own commands under that temperature, and legs shorter by the
    # expansion they would have (alpha * dT * l, first order)
    direct = machine.model.commands(HOME_P, HOME_Q, Conditions(25.0, np.zeros(6)))
    np.testing.assert_allclose(warm, joints_of(direct), rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(warm[:3] - at_nominal[:3], -2e-5 * 5.0 * at_nominal[:3],
                               rtol=1e-3)
    np.testing.assert_allclose(warm[3:], at_nominal[3:], rtol=0.0, atol=1e-12)


def test_each_axis_approaches_in_the_direction_it_moves_and_keeps_it_at_rest() -> None:
    machine = calibrated()
    compensation = Compensation(TEMPERATURE)
    target = joints_of(machine.model.commands(HOME_P, HOME_Q, Conditions(20.0, np.zeros(6))))
    below = target - np.r_[[1e-4] * 3, [1e-3] * 3]
    below[2] = target[2] + 1e-4  # leg 3 comes from above
    below[5] = target[5]  # theta 3 does not move
    approach = compensation.approach_to(machine, HOME_P, HOME_Q, below, 0.0)
    np.testing.assert_array_equal(approach, [1, 1, -1, 1, 1, 0])
    compensation.moved(target + approach * 1e-4, below)
    np.testing.assert_array_equal(compensation.approach, approach)
    # the reversal band enters the command: half a band per side, the sign of the approach
    with_band = joints_of(compensation.model(machine, 0.0).compensate(MECH, HOME_P, HOME_Q))
    np.testing.assert_allclose(with_band - target,
                               approach * np.r_[[5e-6] * 3, [5e-5] * 3], rtol=0, atol=1e-12)
    # a machine without reversal terms keeps whatever it had
    assert not calibrated(reversal=0.0).model.terms.reversal.any()
    kept = compensation.approach_to(calibrated(reversal=0.0), HOME_P, HOME_Q, below, 0.0)
    np.testing.assert_array_equal(kept, approach)


def test_warnings_name_the_envelope_and_a_stale_temperature() -> None:
    rng = np.random.default_rng(4)
    p = HOME_P + rng.uniform(-0.01, 0.01, (20, 3))
    q = np.tile(HOME_Q, (20, 1))
    envelope = envelope_of(MECH, p, q, PAYLOAD.mass, np.linspace(19.0, 23.0, 20))
    machine = calibrated(envelope=envelope)
    compensation = Compensation(TEMPERATURE)
    compensation.temperature.update(21.0, 0.01, now=0.0)
    assert compensation.judge(machine, MECH, PAYLOAD.mass, HOME_P, HOME_Q, 1.0) == ()
    level, _, values = compensation.report(machine, 1.0)
    assert level == 'ok' and values['air_temperature_source'] == 'measured'
    far = HOME_P + np.array([0.05, 0.0, 0.0])
    found = compensation.judge(machine, MECH, 70.0, far, HOME_Q, 100.0)
    assert any('payload 70 kg outside the calibrated 50 to 50 kg' in w for w in found)
    assert any('mm outside the measured positions' in w for w in found)
    assert any('stale after 10 s' in w for w in found)
    level, message, values = compensation.report(machine, 100.0)
    assert level == 'warn' and 'stale' in message and values['warnings']
    # no thermal terms: the temperature does not matter, nothing said of it
    plain = calibrated(expansion=0.0, envelope=envelope)
    assert not any('temperature' in w
                   for w in compensation.judge(plain, MECH, PAYLOAD.mass, HOME_P, HOME_Q, 100.0))


@pytest.fixture()
def mover_and_cell() -> tuple[Mover, InstantCell]:
    sim_settings = parse(PoseMeasurementSettings, node_parameters(CONFIG, 'pose_measurement'))
    sim = PoseMeasurementSimulator(replace(sim_settings,
                                           truth=sim_settings.truth.without_effects()))
    assert sim.location is not None
    settings = replace(SETTINGS, settle_time=0.0, compensation=replace(
        SETTINGS.compensation, mode='model', temperature=TEMPERATURE))
    cell = InstantCell(sim.truth, sim.instrument, sim.location.tracker, sim_settings.targets,
                       np.random.default_rng(7), settings.compensation.samples)
    mover = Mover(settings, cell.machine())
    mover.driver_status(DRIVES_READY)
    assert mover.estimate_pose() is not None  # the encoders have been read
    return mover, cell


def test_the_mover_refuses_a_bad_temperature_and_warns_outside_the_envelope(
        mover_and_cell: tuple[Mover, InstantCell]) -> None:
    mover, _ = mover_and_cell
    assert 'not a number' in mover.air_temperature(float('nan'), 0.01)
    assert 'outside -20 to 60 degC' in mover.air_temperature(99.0, 0.01)
    level, message, _ = mover.compensation_report()
    assert level == 'warn' and 'outside -20 to 60 degC' in message
    assert mover.air_temperature(21.0, 0.01) == ''
    assert mover.compensation.temperature.refused == 2
    rng = np.random.default_rng(5)
    p = HOME_P + rng.uniform(-0.002, 0.002, (20, 3))
    envelope = envelope_of(MECH, p, np.tile(HOME_Q, (20, 1)), PAYLOAD.mass,
                           np.linspace(19.0, 23.0, 20))
    mover.calibration = calibrated(envelope=envelope)
    inside = mover.move('base', HOME_P, HOME_Q)
    assert 'warning' not in inside.reason
    outside = mover.move('base', HOME_P + np.array([0.0, 0.0, 0.005]), HOME_Q)
    assert 'warning: outside the calibration: position' in outside.reason  # moved all the same
    assert mover.compensation_report()[0] == 'warn'
    # the move reversed every leg it moved: the axes' approach now says so
    assert set(mover.compensation.approach[:3]) <= {-1.0, 1.0}


def test_the_stated_uncertainty_holds_the_temperature_in_use() -> None:
    """Model mode states the calibration's uncertainty at the goal; a nominal temperature
    (no reading: sigma 3 K) states more than a measured one (0.1 K) by what the thermal terms
    make of the difference, and a calibration without a file's data states none."""
    x = np.zeros(cp.COUNT)
    x[cp.LEG_EXPANSION] = 2e-5
    cov = np.diag(np.r_[np.full(26, 1e-12), np.zeros(cp.COUNT - 26)])
    model = cp.machine_model(x, MECH, PAYLOAD, STRUCTURE, reference_temperature=20.0)
    file = calfile.Calibration(x, np.sqrt(np.diag(cov)), np.diag(cov) > 0, covariance=cov,
                               reference_temperature=20.0)
    machine = Calibrated(model, None, (), file, MECH)
    compensation = Compensation(TEMPERATURE)
    nominal = compensation.uncertainty(machine, HOME_P, HOME_Q, 0.0)
    compensation.temperature.update(25.0, 0.01, now=1.0)
    measured = compensation.uncertainty(machine, HOME_P, HOME_Q, 1.0)
    assert nominal is not None and measured is not None
    # the thermal part: the legs' expansion over 1 K times the temperature's sigma
    shift = (model.poses(*np.split(joints_of(model.commands(HOME_P, HOME_Q,
                                                            Conditions(25.0))), 2),
                         conditions=Conditions(26.0)).position[0] - HOME_P)
    thermal = np.linalg.norm(shift)
    total_nominal, total_measured = (np.linalg.norm(s[:3]) for s in (nominal, measured))
    assert total_nominal**2 - total_measured**2 == pytest.approx(
        thermal**2 * (3.0**2 - 0.1**2), rel=0.02)
    assert calibrated().pose_covariance(HOME_P, HOME_Q, Conditions(20.0), 0.1) is None
