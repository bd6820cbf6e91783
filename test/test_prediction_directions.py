"""The worst case over every clearance direction (``clearance_direction: any``, issue 12): per
coordinate and of |Δp| / the rotation angle, against dense sampling of gap directions through
the exact vector model (positioning_cell.clearance.VectorClearance), and its certificate."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.clearance import VectorClearance
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import pose_error
from positioning_cell.prediction.extremes import worst_norm
from positioning_cell.prediction.montecarlo import solve_closure
from positioning_cell.prediction.sensitivity import linearise, worst_case
from positioning_cell.prediction.sources import ToleranceSpec, parse_tolerance_spec

FloatArray = NDArray[np.float64]
MECH = Mechanism.default()
R = 0.16e-3
CLEARANCE = {'u_clearance': R, 's_clearance': R}
FULL = {'leg_length': 20e-6, 'u_centre': 20e-6, 's_centre': 20e-6, 'u_clearance': R,
        's_clearance': R, 'encoder_length': 1e-6, 'encoder_theta': 5e-5}
POSES = {
    'home': (MECH.home_position, MECH.home_quaternion),
    'off-centre tilted': (np.array([0.012, -0.009, MECH.home_height + 0.006]),
                          Rotation.from_rotvec([0.06, -0.04, 0.03]).as_quat()),
}


def make_spec(mode: str, tolerances: dict[str, float] = CLEARANCE) -> ToleranceSpec:
    return parse_tolerance_spec({'tolerances': tolerances, 'clearance_direction': mode,
                                 'requirement': {'position': 1e-4, 'orientation': 1e-3}}, MECH)


def ball_columns(spec: ToleranceSpec) -> NDArray[np.int64]:
    return np.array([range(a, b) for a, b in spec.balls])


def full_gaps(spec: ToleranceSpec, n: int, rng: np.random.Generator) -> FloatArray:
    """n source vectors (n, S): every clearance offset at full length r in a direction uniform
    on the sphere (the ball contact of the vector model), every other source 0."""
    cols = ball_columns(spec)
    e = rng.standard_normal((n, len(cols), 3))
    e *= spec.bounds[cols[:, 0]][:, None] / np.linalg.norm(e, axis=2, keepdims=True)
    x = np.zeros((n, len(spec.sources)))
    x[:, cols] = e
    return x


def vector_model_deviations(spec: ToleranceSpec, p: FloatArray, q: FloatArray,
                            x: FloatArray) -> FloatArray:
    """Pose errors (n, 6) of the uncompensated machine with the clearance offsets of x, by the
    exact vector model: nominal IK commands, FK of the machine with displaced joint centres."""
    cols = ball_columns(spec)
    cmd = inverse(MECH, p, q)
    out = np.empty((x.shape[0], 6))
    for k, xs in enumerate(x):
        e = xs[cols]
        model = VectorClearance(tuple(map(tuple, e[:3])),  # type: ignore[arg-type]
                                tuple(map(tuple, e[3:])))  # type: ignore[arg-type]
        att = model.attained_pose(MECH, cmd.lengths, cmd.thetas, cmd.phis)
        assert att.converged.all()
        dp, dr = pose_error(att.position, att.quaternion, p[None], q[None])
        out[k] = np.concatenate([dp[0], dr[0]])
    return out


@pytest.mark.parametrize('pose', list(POSES))
def test_no_sampled_gap_direction_exceeds_the_worst_case(pose: str) -> None:
    p, q = POSES[pose]
    spec = make_spec('any')
    lin = linearise(MECH, spec, p, q)
    matrix = lin.matrix[0]
    x = full_gaps(spec, 100_000, np.random.default_rng(1))
    dev, converged = solve_closure(MECH, lin, x @ lin.source_map[0].T)
    assert converged.all()
    # the closure solve is the exact vector model (checked on a few samples)
    reference = vector_model_deviations(spec, p, q, x[:20])  # FK to its own tolerance
    np.testing.assert_allclose(dev[:20, :3], reference[:, :3], rtol=0, atol=1e-11)
    np.testing.assert_allclose(dev[:20, 3:], reference[:, 3:], rtol=0, atol=1e-9)
    linear = x @ matrix.T
    # second-order slack of the nonlinear machine over the first-order worst case
    total = 6 * R
    slack = np.array([total**2 / MECH.platform_radius] * 3
                     + [total**2 / MECH.platform_radius**2] * 3)
    per_axis = worst_case(matrix, spec.bounds, spec.balls)
    assert np.all(np.abs(linear).max(axis=0) <= per_axis * (1 + 1e-12))
    assert np.all(np.abs(dev).max(axis=0) <= per_axis + slack)
    assert np.all(np.abs(dev - linear).max(axis=0) <= 0.01 * per_axis)
    for rows, unit in ((slice(0, 3), 0), (slice(3, 6), 3)):
        worst = worst_norm(matrix[rows], spec.bounds, spec.balls)
        sampled = np.linalg.norm(linear[:, rows], axis=1).max()
        assert sampled <= worst.attained * (1 + 1e-9) <= worst.bound * (1 + 1e-9)
        assert np.linalg.norm(dev[:, rows], axis=1).max() <= worst.attained + slack[unit]
        leg = worst_norm(linearise(MECH, make_spec('leg'), p, q).matrix[0, rows],
                         make_spec('leg').bounds)
        assert worst.attained > leg.attained
        if unit == 0:  # |dp|: the leg-aligned worst case does not bound random directions
            assert sampled > leg.bound
            assert worst.attained > 1.25 * leg.attained


@pytest.mark.parametrize('pose', list(POSES))
def test_the_attained_worst_direction_reproduces_the_prediction_in_the_vector_model(
        pose: str) -> None:
    p, q = POSES[pose]
    spec = make_spec('any')
    matrix = linearise(MECH, spec, p, q).matrix[0]
    for rows in (slice(0, 3), slice(3, 6)):
        worst = worst_norm(matrix[rows], spec.bounds, spec.balls)
        e = worst.sources[ball_columns(spec)]
        np.testing.assert_allclose(np.linalg.norm(e, axis=1), R, rtol=1e-12)  # full contact
        plus, minus = vector_model_deviations(spec, p, q, np.stack([worst.sources,
                                                                    -worst.sources]))
        # first order: the attained value; the odd part (first + third order) even closer
        assert np.linalg.norm(plus[rows]) == pytest.approx(worst.attained, rel=2e-3)
        odd = (plus[rows] - minus[rows]) / 2
        assert np.linalg.norm(odd) == pytest.approx(worst.attained, rel=1e-4)
        np.testing.assert_allclose(odd / np.linalg.norm(odd), worst.direction, atol=1e-4)
    # each coordinate's worst case (closed form) is attained by e_j = r·T_c,j/|T_c,j|
    per_axis = worst_case(matrix, spec.bounds, spec.balls)
    cols = ball_columns(spec)
    for c in range(6):
        x = np.zeros(len(spec.sources))
        gains = matrix[c, cols]
        x[cols] = R * gains / np.linalg.norm(gains, axis=1, keepdims=True)
        assert matrix[c] @ x == pytest.approx(per_axis[c], rel=1e-12)
        dev = vector_model_deviations(spec, p, q, np.stack([x, -x]))
        assert (dev[0, c] - dev[1, c]) / 2 == pytest.approx(per_axis[c], rel=1e-4)


def test_the_certificate_brackets_the_maximum_and_every_direction_contains_the_leg() -> None:
    p, q = POSES['off-centre tilted']
    for tolerances in (CLEARANCE, FULL):
        any_spec, leg_spec = make_spec('any', tolerances), make_spec('leg', tolerances)
        t_any = linearise(MECH, any_spec, p, q).matrix[0]
        t_leg = linearise(MECH, leg_spec, p, q).matrix[0]
        for rows in (slice(0, 3), slice(3, 6)):
            coarse = worst_norm(t_any[rows], any_spec.bounds, any_spec.balls)
            fine = worst_norm(t_any[rows], any_spec.bounds, any_spec.balls, resolution=256)
            assert coarse.attained <= coarse.bound <= coarse.attained * (1 + np.sqrt(2) / 60)
            assert coarse.attained == pytest.approx(fine.attained, rel=1e-9)
            assert fine.bound <= coarse.bound and coarse.bound <= coarse.simple_bound
            leg = worst_norm(t_leg[rows], leg_spec.bounds, leg_spec.balls)
            assert leg.attained < coarse.attained  # the leg axis is one of the directions


def test_worst_norm_is_exact_on_problems_with_a_known_maximum() -> None:
    rng = np.random.default_rng(4)
    # boxes only: the maximum of a convex function is at a vertex, 2^10 of them
    m = rng.normal(size=(3, 10))
    bounds = rng.uniform(0.5, 2.0, size=10)
    vertices = np.array(list(itertools.product((-1.0, 1.0), repeat=10))) * bounds
    brute = np.linalg.norm(vertices @ m.T, axis=1).max()
    worst = worst_norm(m, bounds)
    assert worst.attained == pytest.approx(brute, rel=1e-12)
    assert np.linalg.norm(m @ worst.sources) == pytest.approx(worst.attained, rel=1e-12)
    assert np.all(np.abs(worst.sources) == bounds)
    # one ball: r times the spectral norm
    m = rng.normal(size=(3, 3))
    worst = worst_norm(m, np.full(3, 0.7), ((0, 3),))
    assert worst.attained == pytest.approx(0.7 * np.linalg.norm(m, 2), rel=1e-9)
    # nothing to bound
    assert worst_norm(np.zeros((3, 4)), np.ones(4)).bound == 0.0
