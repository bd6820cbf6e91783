"""Locating the tracker on base reference targets ("locate instrument"), ROS-free: exact round
trip, the stated registration uncertainty against Monte Carlo, residuals that reveal a moved
target, refusals, and the pose_measurement simulator locating itself from its config."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats
from scipy.spatial.transform import Rotation

from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.errors import ConfigError
from positioning_cell.metrology.instrument import Tracker, TrackerAccuracy
from positioning_cell.metrology.locate import (
    DEFAULT_BASE_TARGETS,
    LocateError,
    LocateSettings,
    locate,
)
from positioning_cell.parameters import parse
from positioning_cell.sim.pose_measurement import (
    PoseMeasurementSettings,
    PoseMeasurementSimulator,
    TruePose,
)
from positioning_cell.sim.tracker import SimulatedTracker, TrackerTruth

ACCURACY = TrackerAccuracy()
BASE = np.asarray(DEFAULT_BASE_TARGETS)
TRUE = TrackerTruth(scale_ppm=0.0, angle_offsets=(0.0, 0.0))  # no systematic errors
INSTRUMENT = SimulatedTracker(TRUE, ACCURACY)


def registration_error(located: Tracker, true: Tracker) -> np.ndarray:
    """(6,) located − true: origin (m) and the base-axis rotation vector of R_loc·R_trueᵀ."""
    rot = Rotation.from_quat(located.orientation) * Rotation.from_quat(true.orientation).inv()
    return np.hstack([np.subtract(located.position, true.position), rot.as_rotvec()])


def read(instrument: SimulatedTracker, samples: int, rng: np.random.Generator,
         base: np.ndarray = BASE) -> np.ndarray:
    return instrument.read(np.broadcast_to(base, (samples, *base.shape)), rng).local


@given(position=st.tuples(*[st.floats(-5.0, 5.0)] * 3).filter(
           lambda p: np.linalg.norm(np.subtract(p, BASE.mean(axis=0))) > 1.0),
       rotvec=st.tuples(*[st.floats(-3.0, 3.0)] * 3))
def test_exact_readings_locate_the_exact_pose(position: tuple[float, float, float],
                                              rotvec: tuple[float, float, float]) -> None:
    true = Tracker(ACCURACY, position, tuple(Rotation.from_rotvec(rotvec).as_quat()))
    location = locate(ACCURACY, BASE, true.to_local(BASE))
    assert np.abs(registration_error(location.tracker, true)).max() <= 1e-9
    assert location.rms <= 1e-9 and location.used.all()
    assert location.samples.tolist() == [1] * len(BASE)


def test_located_pose_within_its_stated_uncertainty() -> None:
    """300 locations from 20 noisy readings per target: the errors are consistent with the
    stated covariance (χ²(6) on average or a little below: the covariance is scaled up when
    the variance factor exceeds 1; none beyond its 1e-4 tail), the residuals with the
    averaged noise (variance factor about 1: a little above, the fit weights by the mean
    variance, not by the full covariance), and the located pose converts readings to within
    a few µm of the true points."""
    rng = np.random.default_rng(21)
    chi2, factors, point_errors = [], [], []
    true = INSTRUMENT.placed
    for _ in range(300):
        location = locate(ACCURACY, BASE, read(INSTRUMENT, 20, rng))
        err = registration_error(location.tracker, true)
        assert location.tracker.covariance is not None
        chi2.append(err @ np.linalg.solve(location.tracker.covariance, err))
        factors.append(location.variance_factor)
        centre = BASE.mean(axis=0)
        point_errors.append(location.tracker.to_base(true.to_local(centre)) - centre)
        residual_norm = np.linalg.norm(location.residuals, axis=1)
        np.testing.assert_allclose(location.rms, np.sqrt(np.mean(residual_norm**2)))
        assert location.max == pytest.approx(residual_norm.max())
    assert 0.6 * 6.0 < np.mean(chi2) < 1.15 * 6.0
    assert max(chi2) < stats.chi2.ppf(1.0 - 1e-4, 6)
    assert 0.8 < np.mean(factors) < 1.6
    assert np.abs(point_errors).max() < 10e-6


def test_a_moved_target_shows_in_the_residuals() -> None:
    """A base target 150 µm from its nominal coordinates: the residuals stand out (in σ, beyond
    the warning limit), the variance factor rises and inflates the stated covariance. (Least
    squares spreads the blunder over all targets: which one moved is not told.)"""
    rng = np.random.default_rng(22)
    moved = BASE.copy()
    moved[4] += [0.0, 150e-6, 0.0]
    readings = read(INSTRUMENT, 20, rng, moved)
    location = locate(ACCURACY, BASE, readings)
    clean = locate(ACCURACY, moved, readings)
    assert np.nanmax(location.normalised) > LocateSettings().residual_limit
    assert location.variance_factor > 10.0 > clean.variance_factor
    assert location.tracker.covariance is not None and clean.tracker.covariance is not None
    assert np.all(np.diag(location.tracker.covariance) > np.diag(clean.tracker.covariance))


def test_hidden_readings_are_averaged_per_target() -> None:
    rng = np.random.default_rng(23)
    readings = read(INSTRUMENT, 10, rng)
    readings[:7, 2] = np.nan
    readings[:, 5] = np.nan
    location = locate(ACCURACY, BASE, readings)
    assert location.samples.tolist() == [10, 10, 3, 10, 10, 0]
    assert np.isnan(location.residuals[5]).all() and np.isnan(location.normalised[5])
    assert location.used.tolist() == [True] * 5 + [False]


def test_too_few_or_degenerate_targets_are_refused() -> None:
    readings = INSTRUMENT.placed.to_local(BASE)
    three = readings.copy()
    three[3:] = np.nan
    with pytest.raises(LocateError, match=r'3 of 6 base targets read; .* at least 4'):
        locate(ACCURACY, BASE, three)
    line = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0],
                     [0.0, 0.2, 0.0]])
    on_line = INSTRUMENT.placed.to_local(line)
    on_line[4] = np.nan
    with pytest.raises(LocateError, match='lie on one line'):
        locate(ACCURACY, line, on_line)
    with pytest.raises(LocateError, match='expected shape'):
        locate(ACCURACY, BASE, readings[:5])
    bad = readings.copy()
    bad[0, 0] = np.inf
    with pytest.raises(LocateError, match='infinite'):
        locate(ACCURACY, BASE, bad)


@pytest.mark.parametrize(('block', 'match'), [
    ({'base_targets': list(np.ravel(DEFAULT_BASE_TARGETS[:3]))},
     'base_targets = .*3 targets given, .* at least 4 in the base frame'),
    ({'base_targets': [0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.2, 0.0, 0.0, 0.3, 0.0, 0.0]},
     'base_targets = .*one line'),
    ({'samples': 0}, 'samples = 0'),
    ({'residual_limit': 0.1}, 'residual_limit = 0.1'),
])
def test_bad_locate_settings_are_refused(block: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse(LocateSettings, block)


def test_the_simulator_locates_itself_and_measures_through_the_registration() -> None:
    """config/cell.yaml (with its systematic errors): the simulator locates the tracker at
    start, not at its true pose (the registration also absorbs part of the systematic error);
    a platform pose measured through it is within the stated covariance of the truth (judging);
    a re-location draws anew."""
    params = node_parameters(load_parameter_file(config_path()), 'pose_measurement')
    sim = PoseMeasurementSimulator(parse(PoseMeasurementSettings, params))
    location = sim.location
    assert location is not None and location.used.all()
    assert sim.locate_status[0] == 'ok', sim.locate_status
    assert np.abs(registration_error(location.tracker, sim.instrument.placed)).max() > 1e-7
    p, q = np.array([0.002, -0.003, 0.197]), Rotation.from_rotvec([0.02, 0.0, 0.05]).as_quat()
    sim.true_pose = TruePose(p, q, 0)
    bound = stats.chi2.ppf(1 - 1e-6, 6)
    for _ in range(20):
        reading = sim.measure()
        assert reading is not None
        rot = Rotation.from_quat(reading.fit.quaternion[0]) * Rotation.from_quat(q).inv()
        err = np.hstack([reading.fit.position[0] - p, rot.as_rotvec()])
        assert err @ np.linalg.solve(reading.fit.covariance[0], err) < bound
    values = sim.location_values()
    assert len(values['locate_residuals_um']) == len(BASE)
    assert 0.0 < values['locate_residual_rms_um'] < 20.0
    ok, message = sim.locate()
    assert ok and 'tracker located on 6/6 base targets' in message
    assert sim.location is not None and sim.location.tracker != location.tracker
    assert sim.stats['locations'] == 2
