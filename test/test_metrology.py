"""The simulated laser tracker, ROS-free: exact fits, the anisotropic MPE noise model and its
systematic part, covariance against Monte Carlo, outliers, occlusion, refusals, and the truth
model's parameter contract. Locating the tracker: test_locate.py."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell import clearance
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.metrology.fit import PoseFit, TooFewTargetsError, fit_pose, pose_covariance
from positioning_cell.metrology.instrument import Tracker, TrackerAccuracy
from positioning_cell.metrology.targets import DEFAULT_TARGETS, TargetLayout
from positioning_cell.parameters import parse
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.sim.tracker import (
    Measurement,
    SimulatedTracker,
    TrackerFaults,
    TrackerTruth,
    measure,
    observe,
)
from positioning_cell.sim.truth import truth_from_params

LAYOUT = TargetLayout()
ACCURACY = TrackerAccuracy()
PLAIN = Tracker(ACCURACY, (2.0, -1.0, 0.8))
# A tracker that is turned and tilted, so no test relies on an identity orientation.
TURNED = Tracker(ACCURACY, (1.5, 2.0, 1.1),
                 tuple(Rotation.from_rotvec([0.1, -0.2, 2.5]).as_quat()))


def ideal(tracker: Tracker, scale_ppm: float = 0.0,
          angle_offsets: tuple[float, float] = (0.0, 0.0)) -> SimulatedTracker:
    """A simulated instrument standing where ``tracker`` says (without systematic errors
    unless given): these tests take its registration as exact, to test the fit alone."""
    return SimulatedTracker(TrackerTruth(tracker.position, tracker.orientation, scale_ppm,
                                         angle_offsets), tracker.accuracy)


def sim_measure(tracker: Tracker, layout: TargetLayout, p: np.ndarray, q: np.ndarray,
                rng: np.random.Generator, faults: TrackerFaults | None = None) -> Measurement:
    return measure(ideal(tracker), tracker, layout, p, q, rng, faults)


def sim_observe(tracker: Tracker, layout: TargetLayout, p: np.ndarray, q: np.ndarray,
                rng: np.random.Generator,
                faults: TrackerFaults | None = None) -> tuple[Measurement, PoseFit]:
    return observe(ideal(tracker), tracker, layout, p, q, rng, faults)


def pose_errors(fit: PoseFit, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(N, 6): fitted − true position (m) and the rotation vector of R_fit·R_trueᵀ (rad),
    the base-axis small rotations of the covariance."""
    rot = Rotation.from_quat(fit.quaternion) * Rotation.from_quat(q).inv()
    return np.hstack([fit.position - p, rot.as_rotvec()])


def any_poses(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n platform poses anywhere near the cell: the fit knows no joint limits."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.5, 0.5, (n, 3)), Rotation.random(n, random_state=rng).as_quat()


def tiled(n: int, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.tile(p, (n, 1)), np.tile(q, (n, 1))


POSE_P = MECH.home_position + np.array([0.004, -0.006, 0.003])
POSE_Q = Rotation.from_rotvec([0.05, -0.03, 0.1]).as_quat()


def test_spherical_round_trip() -> None:
    points = np.random.default_rng(0).uniform(-1.0, 1.0, (1000, 3))
    for tracker in (PLAIN, TURNED):
        readings = tracker.spherical(points)
        np.testing.assert_allclose(tracker.points(readings), points, atol=1e-14)
        np.testing.assert_allclose(readings[:, 0],
                                   np.linalg.norm(points - tracker.position, axis=1))


def test_fit_recovers_exact_pose() -> None:
    p, q = any_poses(500, 1)
    for tracker in (PLAIN, TURNED):
        fit = fit_pose(tracker, LAYOUT, LAYOUT.in_base(p, q))
        err = pose_errors(fit, p, q)
        assert np.abs(err).max() <= 1e-12
        assert fit.rms.max() <= 1e-12 and fit.inliers.all()


def test_fit_recovers_exact_pose_from_three_targets() -> None:
    p, q = any_poses(200, 2)
    points = LAYOUT.in_base(p, q)
    rng = np.random.default_rng(3)
    hidden = np.argsort(rng.random(points.shape[:2]), axis=1)[:, :2]  # hide 2 of 5 per row
    np.put_along_axis(points, hidden[..., None], np.nan, axis=1)
    fit = fit_pose(PLAIN, LAYOUT, points)
    assert (fit.visible.sum(axis=1) == 3).all()
    assert np.abs(pose_errors(fit, p, q)).max() <= 1e-12


def test_noise_statistics_match_the_anisotropic_mpe_model() -> None:
    """Along the beam σ_r = (10 µm + 0.3 µm/m·r) / 2, across it σ_t = (15 µm + 6 µm/m·r) / 2
    in each direction; ≈ 95.4 % of channel errors within the MPE (k = 2, normal errors); the
    model's point covariance matches the sample covariance of many readings, in ``base``."""
    n = 40000
    tracker = TURNED
    p, q = tiled(n, POSE_P, POSE_Q)
    measurement = sim_measure(tracker, LAYOUT, p, q, np.random.default_rng(4))
    true_points = LAYOUT.in_base(p[:1], q[:1])[0]
    distance = np.linalg.norm(true_points - tracker.position, axis=1)
    sigma_r = (10e-6 + 0.3e-6 * distance) / 2.0
    sigma_t = (15e-6 + 6e-6 * distance) / 2.0
    assert np.all(sigma_t > 2.0 * sigma_r)  # a cigar across the line of sight
    true_readings = tracker.spherical(true_points)
    reading_error = tracker.spherical(measurement.points) - true_readings
    scale = np.stack([np.ones_like(distance), distance * np.cos(true_readings[:, 2]), distance],
                     axis=1)  # metres per unit of r, az, el
    channel_error = reading_error * scale
    expected = np.stack([sigma_r, sigma_t, sigma_t], axis=1)
    np.testing.assert_allclose(channel_error.std(axis=0), expected, rtol=0.03)
    within = (np.abs(channel_error) <= 2 * expected).mean()
    assert within == pytest.approx(2 * stats.norm.cdf(2.0) - 1.0, abs=0.003)
    error = measurement.points - true_points
    assert np.abs(error.mean(axis=0)).max() <= 4.5 * sigma_t.max() / np.sqrt(n)
    model = tracker.point_covariance(true_points)
    for t in range(len(true_points)):
        sample = np.cov(error[:, t].T)
        s = np.sqrt(np.diag(model[t]))
        # normalised entries: sampling standard error about 1 / sqrt(n) = 0.005
        assert np.abs((sample - model[t]) / np.outer(s, s)).max() <= 0.03
        # the model's principal axes: σ_r along the beam, σ_t twice across it
        beam = (true_points[t] - tracker.position) / distance[t]
        np.testing.assert_allclose(beam @ model[t] @ beam, sigma_r[t] ** 2, rtol=1e-6)
        np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(model[t])),
                                   np.sort([sigma_r[t] ** 2, sigma_t[t] ** 2, sigma_t[t] ** 2]),
                                   rtol=1e-6)


def test_systematic_errors_survive_averaging() -> None:
    """The range scale (ppm) and the angle offsets are constant: the mean of many readings
    keeps them (its bias is the systematic error, far above the mean's random error)."""
    n = 20000
    truth = TrackerTruth(TURNED.position, TURNED.orientation, scale_ppm=5.0,
                         angle_offsets=(4e-6, -6e-6))
    instrument = SimulatedTracker(truth, ACCURACY)
    true_points = LAYOUT.in_base(POSE_P[None], POSE_Q[None])[0]
    readings = instrument.read(np.broadcast_to(true_points, (n, *true_points.shape)),
                               np.random.default_rng(12))
    mean = readings.local.mean(axis=0)
    true = TURNED.spherical(true_points)
    bias = TURNED.spherical(TURNED.to_base(mean)) - true
    random = ACCURACY.reading_sigma(true) / np.sqrt(n)
    np.testing.assert_allclose(bias[:, 0], 5e-6 * true[:, 0], atol=4.5 * random[:, 0].max())
    np.testing.assert_allclose(bias[:, 1], 4e-6, atol=4.5 * random[:, 1].max())
    np.testing.assert_allclose(bias[:, 2], -6e-6, atol=4.5 * random[:, 2].max())
    assert np.all(np.abs(bias[:, 0]) > 10 * random[:, 0])  # ~10 µm against ~0.04 µm


def test_covariance_matches_monte_carlo() -> None:
    n = 20000
    for tracker in (PLAIN, TURNED):
        p, q = tiled(n, POSE_P, POSE_Q)
        _, fit = sim_observe(tracker, LAYOUT, p, q, np.random.default_rng(5))
        err = pose_errors(fit, POSE_P[None], POSE_Q[None])
        predicted = fit.covariance[0]
        scale = np.sqrt(np.diag(predicted))
        # Evaluated at each fitted pose, the prediction barely changes from reading to reading
        # (a rare 5-sigma residual rejected changes the target set, hence its covariance).
        full = fit.inliers.all(axis=1)
        assert full.mean() >= 0.999
        assert np.abs((fit.covariance[full] - predicted) / np.outer(scale, scale)).max() <= 1e-3
        # Each normalised entry has a sampling standard error of about 1 / sqrt(n) = 0.007.
        normalised = (np.cov(err.T) - predicted) / np.outer(scale, scale)
        assert np.abs(normalised).max() <= 0.04, normalised
        assert np.abs(err.mean(axis=0) / scale).max() <= 4.5 / np.sqrt(n)
        np.linalg.cholesky(predicted)


def test_covariance_grows_with_fewer_targets_and_distance() -> None:
    tracker = PLAIN
    full = pose_covariance(tracker, LAYOUT, POSE_P, POSE_Q)[0]
    three = pose_covariance(tracker, LAYOUT, POSE_P, POSE_Q, [[1, 1, 0, 1, 0]])[0]
    assert np.all(np.diag(three) > np.diag(full))
    far = pose_covariance(Tracker(ACCURACY, (8.0, -4.0, 3.2)), LAYOUT, POSE_P, POSE_Q)[0]
    assert np.all(np.diag(far) > np.diag(full))


def test_outliers_are_rejected() -> None:
    n = 5000
    p, q = tiled(n, POSE_P, POSE_Q)
    faults = TrackerFaults(outlier_probability=0.1, outlier_magnitude=1e-3)
    for layout in (LAYOUT, TargetLayout(DEFAULT_TARGETS[:4])):
        measurement, fit = sim_observe(PLAIN, layout, p, q, np.random.default_rng(6), faults)
        count = measurement.outlier.sum(axis=1)
        one, clean = count == 1, count == 0
        assert one.sum() > 1000 and clean.sum() > 1000
        caught = ((~fit.inliers) == measurement.outlier).all(axis=1)
        assert caught[one].mean() >= 0.99
        assert fit.rejected[clean].sum() <= 2  # a 5 σ residual is rare
        err = pose_errors(fit, POSE_P[None], POSE_Q[None])
        chi2 = np.einsum('ni,nij,nj->n', err, np.linalg.inv(fit.covariance), err)
        good = (one | clean) & caught
        assert np.quantile(chi2[good], 0.99) <= stats.chi2.ppf(0.999, 6)
        assert (fit.rms[good] < 100e-6).all()


def test_single_gross_outlier_does_not_move_the_pose() -> None:
    points = LAYOUT.in_base(POSE_P[None], POSE_Q[None])
    for target in range(len(LAYOUT.platform)):
        wild = points.copy()
        wild[0, target] += [0.002, -0.001, 0.003]
        fit = fit_pose(PLAIN, LAYOUT, wild)
        assert fit.inliers[0].tolist() == [i != target for i in range(len(LAYOUT.platform))]
        assert np.abs(pose_errors(fit, POSE_P, POSE_Q)).max() <= 1e-12
        assert fit.rejected.tolist() == [1]


def test_occlusion_down_to_three_targets() -> None:
    n = 20000
    p, q = tiled(n, POSE_P, POSE_Q)
    faults = TrackerFaults(occlusion_probability=0.3)
    rng = np.random.default_rng(7)
    measurement = sim_measure(PLAIN, LAYOUT, p, q, rng, faults)
    visible = measurement.visible.sum(axis=1)
    keep = visible >= 3
    assert (visible == 3).sum() > 1000 and (~keep).sum() > 100
    with pytest.raises(TooFewTargetsError):
        fit_pose(PLAIN, LAYOUT, measurement.points)
    fit = fit_pose(PLAIN, LAYOUT, measurement.points[keep])
    err = pose_errors(fit, POSE_P[None], POSE_Q[None])
    chi2 = np.einsum('ni,nij,nj->n', err, np.linalg.inv(fit.covariance), err)
    three = visible[keep] == 3
    # With the covariance of each fit's own visible set the errors are χ²(6) distributed.
    for subset in (three, ~three):
        assert np.mean(chi2[subset]) == pytest.approx(6.0, rel=0.05)
    assert np.median(np.trace(fit.covariance[three], axis1=1, axis2=2)) > np.median(
        np.trace(fit.covariance[~three], axis1=1, axis2=2))


def test_draws_stay_aligned_whatever_the_faults() -> None:
    p, q = tiled(200, POSE_P, POSE_Q)
    plain = sim_measure(PLAIN, LAYOUT, p, q, np.random.default_rng(8))
    faulty = sim_measure(PLAIN, LAYOUT, p, q, np.random.default_rng(8),
                     TrackerFaults(occlusion_probability=0.3, outlier_probability=0.2))
    same = faulty.visible & ~faulty.outlier
    assert same.sum() > 300 and not faulty.visible.all() and faulty.outlier.any()
    np.testing.assert_array_equal(faulty.points[same], plain.points[same])


def test_too_few_targets_are_refused() -> None:
    points = LAYOUT.in_base(POSE_P[None], POSE_Q[None])
    points[0, [0, 2, 4]] = np.nan
    with pytest.raises(TooFewTargetsError, match='reading 0: 2 of 5 targets visible'):
        fit_pose(PLAIN, LAYOUT, points)
    # Three visible targets on one line: the rotation about it is undetermined.
    line = TargetLayout(((0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.1, 0.0)))
    points = line.in_base(POSE_P[None], POSE_Q[None])
    points[0, 3] = np.nan
    with pytest.raises(TooFewTargetsError, match='one line'):
        fit_pose(PLAIN, line, points)


@pytest.mark.parametrize(('make', 'match'), [
    (lambda: TrackerAccuracy(range_mpe_constant=0.0), 'range_mpe_constant'),
    (lambda: TrackerAccuracy(transverse_mpe_proportional=-1e-6), 'transverse_mpe_proportional'),
    (lambda: TrackerAccuracy(coverage_factor=float('nan')), 'coverage_factor'),
    (lambda: TrackerTruth(orientation=(0.0, 0.0, 0.0, 2.0)), 'orientation'),
    (lambda: TrackerTruth(position=(0.0, float('inf'), 1.0)), 'position'),
    (lambda: TrackerTruth(angle_offsets=(0.0, 0.5)), 'angle_offsets'),
    (lambda: parse(TrackerAccuracy, {'range': 3.0}, 'tracker.'),
     'tracker.range: unknown parameter'),
    (lambda: parse(TrackerAccuracy, {'position': [1.0, 2.0, 3.0]}, 'tracker.'),
     'tracker.position: unknown parameter'),  # the pose is truth now, the cell locates it
    (lambda: parse(TrackerTruth, {'position': [1.0, 2.0]}), 'expected 3 numbers'),
    (lambda: parse(TrackerAccuracy, {'range_mpe_constant': 'small'}), 'expected a number'),
    (lambda: TargetLayout(DEFAULT_TARGETS[:3]), 'at least 4'),
    (lambda: TargetLayout(((0, 0, 0), (0.1, 0, 0), (0.2, 0, 0), (0.3, 0, 0))), 'one line'),
    (lambda: TargetLayout(((0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.0005))), 'apart'),
    (lambda: parse(TargetLayout, {'platform': [0.1] * 14}), 'expected rows of 3 numbers'),
    (lambda: parse(TargetLayout, {'platform': [0.1, 'x', 0.2]}), 'expected a list of numbers'),
    (lambda: TrackerFaults(occlusion_probability=1.5), 'occlusion_probability'),
    (lambda: TrackerFaults(outlier_probability=-0.1), 'outlier_probability'),
    (lambda: TrackerFaults(outlier_magnitude=float('inf')), 'outlier_magnitude'),
    (lambda: truth_from_params({'clearance.model': 'ideal', 'clearance.seed': 0}, MECH),
     'truth.clearance.model'),
    (lambda: truth_from_params({'clearance.r_a': -1e-4, 'clearance.seed': 0}, MECH),
     'truth.clearance.r_a'),
    (lambda: truth_from_params({'clearance.seed': -3}, MECH),
     r'truth.clearance.seed = -3: must be in \[-1, '),
    (lambda: truth_from_params({'clearance.seed': True}, MECH),
     'truth.clearance.seed = True: expected an integer'),
    (lambda: truth_from_params({'clearance.model': 'vector', 'clearance.seed': -1}, MECH),
     "truth.clearance.seed = -1: the vector model's directions are not all given"),
    (lambda: truth_from_params({'base_offsets': [0.0] * 8}, MECH),
     'truth.base_offsets = .*: expected 9 numbers'),
    (lambda: truth_from_params({'gravity': 9.81}, MECH), 'truth.gravity: unknown parameter'),
    (lambda: parse(PoseMeasurementSettings, {'fault': {'dropout': 0.1}}),
     'fault.dropout: unknown parameter'),
    (lambda: parse(PoseMeasurementSettings, {'fit.reject_threshold': -1.0}),
     r'fit.reject_threshold = -1.0: must be in \[1, 1000\]'),
    (lambda: parse(PoseMeasurementSettings, {'mechanism.base_radius': -0.1}),
     'mechanism.base_radius = -0.1: must be > 0 m'),
    (lambda: parse(PoseMeasurementSettings, {'truth.tracker.scale_ppm': 'warm'}),
     'truth.tracker.scale_ppm = .*: expected a number'),
    (lambda: parse(PoseMeasurementSettings, {'locate.base_targets': [0.0] * 9}),
     'locate.base_targets = .*at least 4'),
])
def test_bad_parameters_are_refused(make: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make()  # type: ignore[operator]


def test_bad_fit_input_is_refused() -> None:
    points = LAYOUT.in_base(POSE_P[None], POSE_Q[None])
    with pytest.raises(InputError, match=r'expected shape \(5, 3\)'):
        fit_pose(PLAIN, LAYOUT, points[:, :4])
    bad = points.copy()
    bad[0, 1, 2] = np.inf
    with pytest.raises(InputError, match='infinite'):
        fit_pose(PLAIN, LAYOUT, bad)
    with pytest.raises(InputError, match='reject_threshold'):
        fit_pose(PLAIN, LAYOUT, points, reject_threshold=0.0)
    with pytest.raises(InputError, match='quaternion'):
        sim_measure(PLAIN, LAYOUT, POSE_P, np.zeros(4), np.random.default_rng(0))
    with pytest.raises(InputError, match='coincides'):
        sim_measure(Tracker(ACCURACY, tuple(LAYOUT.in_base(POSE_P[None], POSE_Q[None])[0, 2])),
                    LAYOUT, POSE_P, POSE_Q, np.random.default_rng(0))


@pytest.mark.parametrize('kind', ['effective_length', 'vector'])
def test_truth_reproduces_a_compensation_block_with_the_same_seed(kind: str) -> None:
    """The positioner's compensation.clearance.* block with the truth's keys and seed builds
    the very model the simulator holds (the cell's `model` compensation test relies on it)."""
    block = {'model': kind, 'r_a': 1.2e-4, 'r_b': 1.6e-4, 'seed': 11}
    truth = truth_from_params({f'clearance.{k}': v for k, v in block.items()}, MECH)
    positioner = clearance.model_from_params(block, MECH)
    assert truth.clearance == positioner
    assert truth.mechanism == MECH
    other = truth_from_params({'clearance': {**block, 'seed': 12}}, MECH)
    assert other.clearance != truth.clearance


def test_truth_geometric_errors_and_attained_pose() -> None:
    base = np.arange(9.0).reshape(3, 3) * 1e-5
    platform = -np.arange(9.0).reshape(3, 3) * 2e-5
    truth = truth_from_params({'truth.clearance.model': 'none',
                               'truth.base_offsets': base.ravel().tolist(),
                               'truth.platform_offsets': platform.ravel().tolist()}, MECH)
    assert truth.clearance is None
    np.testing.assert_allclose(truth.mechanism.base_joints - MECH.base_joints, base)
    np.testing.assert_allclose(truth.mechanism.platform_joints - MECH.platform_joints, platform)
    joints = inverse(MECH, MECH.home_position, MECH.home_quaternion)
    nominal = truth_from_params({'clearance.model': 'none'}, MECH)
    result = nominal.poses(joints.lengths, joints.thetas, joints.phis)
    np.testing.assert_allclose(result.position[0], MECH.home_position, atol=1e-12)
    moved = truth.poses(joints.lengths, joints.thetas, joints.phis)
    assert 1e-5 < np.abs(moved.position[0] - MECH.home_position).max() < 1e-3


def test_shipped_config_builds_a_truth_with_the_machine_errors() -> None:
    """config/cell.yaml's pose_measurement section: a valid truth (load-driven clearance and
    the geometric errors of seed 0), tracker and layout, and an uncompensated home pose off by
    tens to hundreds of µm."""
    params = node_parameters(load_parameter_file(config_path()), 'pose_measurement')
    settings = parse(PoseMeasurementSettings, params)
    assert settings.tracker == TrackerAccuracy() and settings.targets == TargetLayout()
    assert settings.truth.tracker == TrackerTruth()
    assert settings.fault == TrackerFaults() and settings.fit.reject_threshold == 5.0
    mech = settings.mechanism
    joints = inverse(mech, mech.home_position, mech.home_quaternion)
    attained = settings.true_machine().poses(joints.lengths, joints.thetas, joints.phis)
    dp = attained.position[0] - mech.home_position
    assert 10e-6 < np.linalg.norm(dp) < 1e-3
    truth = settings.true_machine()
    assert truth.clearance is not None and np.any(truth.length_offsets)
    assert np.any(truth.mechanism.base_offsets) and np.any(truth.theta_offsets)
