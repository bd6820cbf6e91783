"""Sensitivity T = C − D·U⁻¹·A (seed 004 eq. 14) against finite differences of the full
nonlinear forward kinematics, and the worst case (eq. 15) against the nonlinear machine."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.core.kinematics import forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import pose_error
from positioning_cell.prediction.sensitivity import (
    kind_variances,
    linearise,
    root_sum_square,
    worst_case,
)
from positioning_cell.prediction.sources import ToleranceSpec, parse_tolerance_spec

MECH = Mechanism.default()
TOL = {'leg_length': 20e-6, 'u_centre': 20e-6, 's_centre': 20e-6, 'u_clearance': 0.16e-3,
       's_clearance': 0.16e-3, 'encoder_length': 1e-6, 'encoder_theta': 5e-5}
POSES = {
    'home': (MECH.home_position, MECH.home_quaternion),
    'off-centre tilted': (np.array([0.012, -0.009, MECH.home_height + 0.006]),
                          Rotation.from_rotvec([0.06, -0.04, 0.03]).as_quat()),
}


def make_spec(mode: str = 'leg') -> ToleranceSpec:
    return parse_tolerance_spec({'tolerances': TOL, 'clearance_direction': mode,
                                 'motion': [0.01, -0.02, 0.05, 0.1, 0.0, 0.2],
                                 'requirement': {'position': 1e-4, 'orientation': 1e-3}}, MECH)


def nonlinear_deviation(spec: ToleranceSpec, p: NDArray[np.float64], q: NDArray[np.float64],
                        x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pose error (6,) of the machine with sources x, by kinematics.forward on the displaced
    joint centres: the independent, full nonlinear model."""
    lin = linearise(MECH, spec, p, q)
    prim = lin.source_map[0] @ x
    mech = MECH.with_offsets(prim[6:15].reshape(3, 3), prim[15:24].reshape(3, 3))
    joints = inverse(MECH, p, q)
    result = forward(mech, joints.lengths + prim[0:3], joints.thetas + prim[3:6], joints.phis)
    assert result.converged.all()
    dp, drot = pose_error(result.position, result.quaternion, p[None], q[None])
    return np.concatenate([dp[0], drot[0]])


@pytest.mark.parametrize('mode', ['leg', 'motion', 'any'])
@pytest.mark.parametrize('pose', list(POSES))
def test_sensitivity_matches_finite_differences_of_forward_kinematics(pose: str,
                                                                      mode: str) -> None:
    spec = make_spec(mode)
    p, q = POSES[pose]
    matrix = linearise(MECH, spec, p, q).matrix[0]
    h = 1e-6
    fd = np.empty_like(matrix)
    for j in range(matrix.shape[1]):
        e = np.zeros(matrix.shape[1])
        e[j] = h
        fd[:, j] = (nonlinear_deviation(spec, p, q, e) - nonlinear_deviation(spec, p, q, -e)) / (
            2 * h)
    np.testing.assert_allclose(matrix, fd, rtol=0, atol=1e-6 * np.abs(matrix).max())


def test_gap_connectors_along_the_leg_act_as_length_changes() -> None:
    # A U centre displaced by x along the leg lengthens it by x; a ball displaced by x along the
    # leg shortens it by x (docs/conventions/kinematics.md, seed 000 eq. 9 with the gap along the
    # leg).
    spec = make_spec('leg')
    matrix = linearise(MECH, spec, *POSES['off-centre tilted']).matrix[0]
    col = {n: matrix[:, j] for j, n in enumerate(spec.names)}
    for leg in (1, 2, 3):
        np.testing.assert_allclose(col[f'u_clearance_{leg}'], col[f'leg_length_{leg}'],
                                   atol=1e-12)
        np.testing.assert_allclose(col[f's_clearance_{leg}'], -col[f'leg_length_{leg}'],
                                   atol=1e-12)


def test_worst_case_is_reached_by_the_nonlinear_machine_at_the_extreme_vertex() -> None:
    spec = make_spec('leg')
    p, q = POSES['off-centre tilted']
    matrix = linearise(MECH, spec, p, q).matrix[0]
    bound = worst_case(matrix, spec.bounds)
    for c in range(6):
        vertex = np.sign(matrix[c]) * spec.bounds
        plus = nonlinear_deviation(spec, p, q, vertex)[c]
        minus = nonlinear_deviation(spec, p, q, -vertex)[c]
        odd, even = (plus - minus) / 2, (plus + minus) / 2  # first + third order, second order
        assert odd == pytest.approx(bound[c], rel=1e-3)  # seed 004 eq. 15 is attained
        assert abs(even) < 0.05 * bound[c]  # and the second-order slack is small
        assert abs(plus - bound[c]) <= abs(even) + 1e-3 * bound[c]


def test_rss_and_variance_split_add_up() -> None:
    spec = make_spec('leg')
    matrix = linearise(MECH, spec, *POSES['home']).matrix[0]
    rss = root_sum_square(matrix, spec.bounds)
    assert np.all(rss <= worst_case(matrix, spec.bounds) + 1e-18)
    kinds, variances = kind_variances(matrix, spec)
    sigma = root_sum_square(matrix, spec.stds)
    assert variances.shape == (2, len(kinds))
    assert variances[0].sum() == pytest.approx(np.sum(sigma[:3] ** 2))
    assert variances[1].sum() == pytest.approx(np.sum(sigma[3:] ** 2))
