"""Inverse and forward kinematics and the Jacobian, verified independently: round trips, a
second FK solver (scipy least squares on the full closure in pose space), finite differences."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp
from workspace import MECH, poses, random_poses

from positioning_cell.core import kinematics
from positioning_cell.core.limits import check_poses
from positioning_cell.core.poses import (
    SMALL_BATCH,
    canonical_quaternions,
    euler_xyz_from_quaternion,
    matrix_from_quaternion,
    mean_quaternion,
    quaternion_from_euler_xyz,
    quaternion_from_matrix,
    quaternion_from_rotation_vector,
    quaternion_inverse,
    quaternion_product,
    rotate,
    rotation_angle,
    rotation_vector,
    slerp,
)
from positioning_cell.errors import InputError
from positioning_cell.testing.reference_kinematics import reference_forward


def rotation_error(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return (Rotation.from_quat(q1).inv() * Rotation.from_quat(q2)).magnitude()


@given(poses())
def test_ik_fk_round_trip_property(pose: tuple[np.ndarray, np.ndarray]) -> None:
    p, q = pose
    assume(check_poses(MECH, p, q).ok)
    joints = kinematics.inverse(MECH, p, q)
    fk = kinematics.forward(MECH, joints.lengths, joints.thetas)
    assert fk.converged.all()
    assert np.abs(fk.position[0] - p).max() <= 1e-12
    assert rotation_error(fk.quaternion, q).max() <= 1e-12
    np.testing.assert_allclose(fk.phis, joints.phis, atol=1e-10)


@given(st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 4)
                .filter(lambda v: float(np.linalg.norm(v)) > 0.05), min_size=1, max_size=8))
def test_rotation_matrices_are_scipys(quaternions: list[tuple[float, ...]]) -> None:
    """core.poses' numpy quaternion -> matrix (every node's build uses it instead of scipy,
    issue 24) against scipy's, for any quaternion, normalised as scipy normalises it: a batch
    and one alone (its path in Python floats)."""
    q = np.array(quaternions)
    expected = Rotation.from_quat(q).as_matrix()
    np.testing.assert_allclose(matrix_from_quaternion(q), expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(matrix_from_quaternion(q[0]), expected[0], rtol=0, atol=1e-14)


@given(st.lists(st.tuples(*[st.floats(-2 * np.pi, 2 * np.pi)] * 3), min_size=1, max_size=8))
def test_euler_quaternions_are_scipys(angles: list[tuple[float, ...]]) -> None:
    """core.poses' numpy Euler angles (extrinsic x, y, z) -> quaternion, the positioner's
    factory box and Transform.from_pose6 (issue 24), against scipy's, sign included."""
    a = np.array(angles)
    np.testing.assert_allclose(quaternion_from_euler_xyz(a),
                               Rotation.from_euler('xyz', a).as_quat(), rtol=0, atol=1e-15)


@given(st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 4)
                .filter(lambda v: float(np.linalg.norm(v)) > 0.05), min_size=1, max_size=8))
def test_euler_angles_of_quaternions_are_scipys(quaternions: list[tuple[float, ...]]) -> None:
    """core.poses' numpy quaternion -> Euler angles (extrinsic x, y, z; the watch window's and
    the command line's six numbers without scipy.spatial, issue 24) against scipy's, for any
    quaternion: the same rotation, in scipy's ranges, and scipy's angles (an angle of −π and
    one of π the same) wherever they are well conditioned (away from gimbal lock, where α and
    γ are not separable)."""
    q = np.array(quaternions)
    angles = euler_xyz_from_quaternion(q)
    assert np.all(np.abs(angles[:, [0, 2]]) <= np.pi)
    assert np.all(np.abs(angles[:, 1]) <= np.pi / 2)
    assert rotation_error(quaternion_from_euler_xyz(angles), q).max() <= 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # scipy's "Gimbal lock detected"
        expected = Rotation.from_quat(q).as_euler('xyz')
    clear = np.cos(expected[:, 1]) > 1e-3
    apart = (angles[clear] - expected[clear] + np.pi) % (2 * np.pi) - np.pi  # -π is π
    np.testing.assert_allclose(apart, 0.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize('beta', [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 5e-8,
                                  np.pi / 2 - 1e-6, -np.pi / 2 + 1e-5])
@pytest.mark.parametrize(('alpha', 'gamma'), [(0.3, 0.2), (3.1, -3.0), (-2.5, 2.9)])
def test_euler_angles_at_gimbal_lock_are_scipys(beta: float, alpha: float,
                                                gamma: float) -> None:
    """At and near gimbal lock (β = ±π/2): within 1e-7 rad of it γ = 0 and α takes the whole
    turn about the locked axis, as scipy does (without its warning); just outside, both give
    the angles the rotation was made of."""
    q = Rotation.from_euler('xyz', [alpha, beta, gamma]).as_quat()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # scipy's "Gimbal lock detected"
        expected = Rotation.from_quat(q).as_euler('xyz')
    with warnings.catch_warnings():
        warnings.simplefilter('error')  # none here
        angles = euler_xyz_from_quaternion(q[None])[0]
    np.testing.assert_allclose(angles, expected, rtol=0, atol=1e-9)


@given(st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 4)
                .filter(lambda v: float(np.linalg.norm(v)) > 0.05), min_size=1,
                max_size=SMALL_BATCH),
       st.sampled_from([(), (0,), (1,), (2,)]))
def test_small_batches_of_matrices_give_scipys_canonical_quaternions(
        quaternions: list[tuple[float, ...]], half_turn: tuple[int, ...]) -> None:
    """core.poses' numpy matrix -> quaternion for a few orthonormal matrices (Shepperd's
    method: a node's build converts one or two, issue 24) against scipy's canonical ones, with
    half turns about an axis (w = 0, where the sign rule reaches the next component) too."""
    q = np.array(quaternions)
    if half_turn:
        q[0] = np.eye(4)[half_turn[0]] * (-1.0 if q[0, 0] < 0 else 1.0)
    matrices = Rotation.from_quat(q).as_matrix()
    got = quaternion_from_matrix(matrices, orthonormal=True)
    expected = Rotation.from_matrix(matrices, assume_valid=True).as_quat(canonical=True)
    np.testing.assert_allclose(got, expected, rtol=0, atol=5e-15)
    big = np.repeat(matrices, SMALL_BATCH + 1, axis=0)  # scipy's path, the same quaternions
    np.testing.assert_allclose(quaternion_from_matrix(big, orthonormal=True)[::SMALL_BATCH + 1],
                               expected, rtol=0, atol=5e-15)


@given(st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 4)
                .filter(lambda v: float(np.linalg.norm(v)) > 0.05), min_size=1, max_size=12),
       st.floats(1e-6, 0.5), st.lists(st.booleans(), min_size=12, max_size=12))
def test_mean_quaternions_are_scipys(centres: list[tuple[float, ...]], spread: float,
                                     flips: list[bool]) -> None:
    """core.poses' numpy chordal mean (the tracker's and the monitor's averages of readings,
    issue 24) against scipy's ``Rotation.mean``: readings scattered by ``spread`` rad about a
    drawn rotation, some given with the other sign (the same rotation). Where the two largest
    eigenvalues are close the mean is ill-defined; drawn sets there are skipped."""
    q0 = Rotation.from_quat(centres[0])
    turns = np.array(centres[1:] + [(0.0, 0.0, 0.0, 1.0)]) * spread
    q = (Rotation.from_rotvec(turns[:, :3]) * q0).as_quat()
    q[np.array(flips[:len(q)])] *= -1.0
    eigenvalues = np.linalg.eigvalsh(q.T @ q / len(q))
    assume(eigenvalues[-1] - eigenvalues[-2] > 1e-3)
    expected = Rotation.from_quat(q).mean().as_quat(canonical=True)
    np.testing.assert_allclose(mean_quaternion(q), expected, rtol=0, atol=1e-12)


#: Unit quaternions drawn anywhere (normalised from any direction), as lists for hypothesis.
UNIT_QUATERNIONS = st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 4)
                            .filter(lambda v: float(np.linalg.norm(v)) > 0.05),
                            min_size=1, max_size=8).map(
    lambda qs: np.array(qs) / np.linalg.norm(qs, axis=1, keepdims=True))


@given(UNIT_QUATERNIONS, UNIT_QUATERNIONS, st.lists(st.floats(-1.0, 1.0), min_size=3,
                                                    max_size=3))
def test_numpy_rotations_are_scipys(a: np.ndarray, b: np.ndarray, v: list[float]) -> None:
    """core.poses' numpy rotations (the positioner's moves, corrections and status without
    scipy.spatial, issue 24) against scipy's Rotation: products, inverses, rotation vectors
    both ways, rotated vectors and angles, sign included where scipy keeps it."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    ra, rb = Rotation.from_quat(a), Rotation.from_quat(b)
    np.testing.assert_allclose(quaternion_product(a, b), (ra * rb).as_quat(), rtol=0,
                               atol=1e-15)
    np.testing.assert_allclose(quaternion_inverse(a), ra.inv().as_quat(), rtol=0, atol=5e-16)
    np.testing.assert_allclose(rotation_vector(a), ra.as_rotvec(), rtol=0, atol=5e-15)
    np.testing.assert_allclose(rotation_angle(a), ra.magnitude(), rtol=0, atol=5e-15)
    turns = ra.as_rotvec() * np.array(v[:1] + [1.0] * (n - 1))[:, None]  # small angles too
    np.testing.assert_allclose(quaternion_from_rotation_vector(turns),
                               Rotation.from_rotvec(turns).as_quat(), rtol=0, atol=5e-16)
    np.testing.assert_allclose(rotate(a, np.array(v)), ra.apply(v), rtol=0, atol=1e-14)
    np.testing.assert_allclose(canonical_quaternions(-a), ra.as_quat(canonical=True), rtol=0,
                               atol=5e-16)


@given(UNIT_QUATERNIONS, st.lists(st.floats(0.0, 1.0), min_size=1, max_size=20))
def test_numpy_slerp_is_scipys(q: np.ndarray, fractions: list[float]) -> None:
    """core.poses.slerp (a move's orientations, moves.trajectory) against scipy's Slerp between
    two drawn rotations (one and the next; the last and itself), ends included."""
    start, end = q[0], q[-1] if len(q) > 1 else q[0]
    s = np.array([0.0, 1.0, *fractions])
    expected = Slerp([0.0, 1.0], Rotation.from_quat([start, end]))(s).as_quat()
    np.testing.assert_allclose(slerp(start, end, s), expected, rtol=0, atol=1e-14)


@given(st.floats(1e-12, 2e-3))
def test_small_rotation_vectors_keep_their_bits(angle: float) -> None:
    """Across scipy's series threshold (1e-3 rad) and far below it, a rotation vector survives
    the round trip to a quaternion and back to its relative rounding."""
    v = np.array([0.6, -0.8, 0.0]) * angle
    np.testing.assert_allclose(rotation_vector(quaternion_from_rotation_vector(v)), v,
                               rtol=1e-15, atol=0)


def test_ik_fk_round_trip_batch() -> None:
    p, q = random_poses(5000, np.random.default_rng(1))
    joints = kinematics.inverse(MECH, p, q)
    fk = kinematics.forward(MECH, joints.lengths, joints.thetas)
    assert fk.converged.all()
    assert np.abs(fk.position - p).max() <= 1e-12
    assert rotation_error(fk.quaternion, q).max() <= 1e-12


def test_fk_ik_round_trip_from_joints() -> None:
    """Joint space → pose → joint space, for joints drawn around home."""
    rng = np.random.default_rng(2)
    home = kinematics.inverse(MECH, MECH.home_position, MECH.home_quaternion)
    lengths = home.lengths + rng.uniform(-0.01, 0.01, (2000, 3))
    thetas = rng.uniform(-0.1, 0.1, (2000, 3))
    fk = kinematics.forward(MECH, lengths, thetas)
    assert fk.converged.all()
    back = kinematics.inverse(MECH, fk.position, fk.quaternion)
    np.testing.assert_allclose(back.lengths, lengths, atol=1e-12)
    np.testing.assert_allclose(back.thetas, thetas, atol=1e-12)


def test_fk_matches_independent_solver() -> None:
    p, q = random_poses(20, np.random.default_rng(3))
    joints = kinematics.inverse(MECH, p, q)
    fk = kinematics.forward(MECH, joints.lengths, joints.thetas)
    for i in range(len(p)):
        position, other = reference_forward(MECH, joints.lengths[i], joints.thetas[i])
        assert np.abs(position - fk.position[i]).max() <= 1e-11
        assert rotation_error(other[None], fk.quaternion[i:i + 1])[0] <= 1e-10


def test_jacobian_matches_finite_differences() -> None:
    p, q = random_poses(10, np.random.default_rng(4))
    jac = kinematics.jacobian(MECH, p, q)
    joints = kinematics.inverse(MECH, p, q)
    q_act = np.hstack([joints.lengths, joints.thetas])
    h = 1e-7
    for k in range(6):
        step = np.zeros(6)
        step[k] = h
        plus = kinematics.forward(MECH, (q_act + step)[:, :3], (q_act + step)[:, 3:], joints.phis)
        minus = kinematics.forward(MECH, (q_act - step)[:, :3], (q_act - step)[:, 3:],
                                   joints.phis)
        v = (plus.position - minus.position) / (2 * h)
        w = (Rotation.from_quat(plus.quaternion) * Rotation.from_quat(minus.quaternion).inv()
             ).as_rotvec() / (2 * h)
        np.testing.assert_allclose(jac.matrix[:, :3, k], v, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(jac.matrix[:, 3:, k], w, rtol=1e-5, atol=1e-5)


def test_inverse_jacobian_is_the_inverse() -> None:
    p, q = random_poses(50, np.random.default_rng(5))
    product = kinematics.inverse_jacobian(MECH, p, q) @ kinematics.jacobian(MECH, p, q).matrix
    np.testing.assert_allclose(product, np.broadcast_to(np.eye(6), product.shape), atol=1e-9)


def test_conditioning_in_unit_interval_and_home_well_conditioned() -> None:
    p, q = random_poses(200, np.random.default_rng(6))
    cond = kinematics.jacobian(MECH, p, q).conditioning
    assert np.all((cond > 0.0) & (cond <= 1.0))
    home = kinematics.jacobian(MECH, MECH.home_position, MECH.home_quaternion).conditioning[0]
    assert home > MECH.min_conditioning


def test_single_pose_is_a_batch_of_one() -> None:
    joints = kinematics.inverse(MECH, MECH.home_position, MECH.home_quaternion)
    assert joints.lengths.shape == joints.thetas.shape == joints.phis.shape == (1, 3)
    np.testing.assert_allclose(joints.lengths, MECH.home_length, atol=1e-15)
    np.testing.assert_allclose(joints.thetas, 0.0, atol=1e-15)
    fk = kinematics.forward(MECH, joints.lengths[0], joints.thetas[0])
    assert fk.position.shape == (1, 3) and fk.quaternion.shape == (1, 4)


def test_branch_continuity_from_previous_solution() -> None:
    """A warm start from the previous φ converges to the same pose as a start from home."""
    p, q = random_poses(200, np.random.default_rng(7))
    joints = kinematics.inverse(MECH, p, q)
    warm = kinematics.forward(MECH, joints.lengths, joints.thetas, joints.phis + 1e-3)
    assert warm.converged.all()
    assert np.abs(warm.position - p).max() <= 1e-12


def test_fk_reports_non_convergence_never_a_pose() -> None:
    # Legs of 30 mm cannot bring base points 173 mm apart to a 104 mm triangle.
    fk = kinematics.forward(MECH, np.full((2, 3), 0.03), np.zeros((2, 3)))
    assert not fk.converged.any()
    assert np.isnan(fk.position).all() and np.isnan(fk.quaternion).all()


def test_fk_mixed_batch_keeps_good_poses() -> None:
    joints = kinematics.inverse(MECH, MECH.home_position, MECH.home_quaternion)
    lengths = np.vstack([joints.lengths, np.full((1, 3), 0.03), joints.lengths])
    fk = kinematics.forward(MECH, lengths, np.zeros((3, 3)))
    assert fk.converged.tolist() == [True, False, True]
    np.testing.assert_allclose(fk.position[[0, 2]], np.tile(MECH.home_position, (2, 1)),
                               atol=1e-12)


@pytest.mark.parametrize(('position', 'quaternion', 'words'), [
    ([0.0, np.nan, 0.2], [0, 0, 0, 1], 'not finite'),
    ([0.0, 0.0, np.inf], [0, 0, 0, 1], 'not finite'),
    ([0.0, 0.0, 0.2], [0, 0, 0, 0], 'is zero'),
    ([0.0, 0.0, 0.2], [0, 0, 0, 1.01], 'norm 1.01'),
    ([0.0, 0.0, 0.2], [0, 0, np.nan, 1], 'not finite'),
    ([0.0, 0.2], [0, 0, 0, 1], 'position: expected shape'),
    ([0.0, 0.0, 0.2], [0, 0, 1], 'quaternion: expected shape'),
    ([[0.0, 0.0, 0.2]] * 2, [0, 0, 0, 1], 'position has 2 poses but quaternion has 1'),
    ('abc', [0, 0, 0, 1], 'position'),
])
def test_bad_input_is_named(position: object, quaternion: object, words: str) -> None:
    with pytest.raises(InputError, match=words):
        kinematics.inverse(MECH, position, quaternion)  # type: ignore[arg-type]


def test_nearly_unit_quaternion_is_normalised() -> None:
    q = np.array([0.0, 0.0, 0.0, 1.0 + 5e-7])
    joints = kinematics.inverse(MECH, MECH.home_position, q)
    np.testing.assert_allclose(joints.lengths, MECH.home_length, atol=1e-15)


def test_forward_bad_input() -> None:
    with pytest.raises(InputError, match='lengths has 2 rows but thetas has 1'):
        kinematics.forward(MECH, np.full((2, 3), 0.2), np.zeros((1, 3)))
    with pytest.raises(InputError, match='must be > 0'):
        kinematics.forward(MECH, [0.2, -0.2, 0.2], [0, 0, 0])
    with pytest.raises(InputError, match='not finite'):
        kinematics.forward(MECH, [0.2, np.nan, 0.2], [0, 0, 0])
    with pytest.raises(InputError, match='tolerance'):
        kinematics.forward(MECH, [0.2, 0.2, 0.2], [0, 0, 0], tolerance=0.0)
    with pytest.raises(InputError, match='max_iterations'):
        kinematics.forward(MECH, [0.2, 0.2, 0.2], [0, 0, 0], max_iterations=0)


def test_forward_takes_any_array_layout_with_one_compiled_kernel() -> None:
    """Read-only, strided and Fortran-ordered inputs give the very poses plain arrays give, and
    the compiled kernel is never specialised again for them (no compile pause in a node)."""
    kinematics.warm_up()  # numba loaded: forward() takes the kernel for any batch
    p, q = random_poses(50, np.random.default_rng(3))
    joints = kinematics.inverse(MECH, p, q)
    plain = kinematics.forward(MECH, joints.lengths, joints.thetas, joints.phis + 1e-3)
    strided = np.repeat(joints.lengths, 2, axis=1)[:, ::2]
    read_only = joints.thetas.copy()
    read_only.setflags(write=False)
    other = kinematics.forward(MECH, strided, read_only, np.asfortranarray(joints.phis + 1e-3))
    home_start = kinematics.forward(MECH, strided, read_only)
    for result in (other, home_start):
        np.testing.assert_array_equal(result.converged, plain.converged)
        np.testing.assert_allclose(result.position, plain.position, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(other.phis, plain.phis)
    assert len(kinematics._forward_kernel.signatures) == 1


def test_compiled_kernel_computes_what_its_python_source_says() -> None:
    """The kernel run as plain Python (numba's py_func) and compiled agree: compilation changes
    speed, not results."""
    p, q = random_poses(20, np.random.default_rng(4))
    joints = kinematics.inverse(MECH, p, q)
    n = len(p)
    outputs = []
    for run in (kinematics._forward_kernel, kinematics._forward_kernel.py_func):
        out = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3, 3)), np.empty(n, dtype=bool))
        run(joints.lengths.copy(), joints.thetas.copy(), kinematics.home_phis(MECH)[None],
            *kinematics._closure_constants(MECH), kinematics.FK_TOLERANCE, 40, *out)
        outputs.append(out)
    for compiled, interpreted in zip(*outputs, strict=True):
        np.testing.assert_allclose(compiled, interpreted, rtol=0, atol=1e-15)
    assert outputs[0][3].all()


def _both_runs(lengths: np.ndarray, thetas: np.ndarray, start: np.ndarray
               ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """The forward kernel's outputs (phis, position, rot, converged), compiled and run as its
    Python source (what a node without numba runs)."""
    kinematics.warm_up()
    n = len(lengths)
    runs = []
    for run in (kinematics._forward_kernel, kinematics._forward_kernel.py_func):
        out = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3, 3)), np.empty(n, dtype=bool))
        run(lengths.copy(), thetas.copy(), start.copy(), *kinematics._closure_constants(MECH),
            kinematics.FK_TOLERANCE, 40, *out)
        runs.append(out)
    return runs[0], runs[1]


def _assert_same(kernel: tuple[np.ndarray, ...], source: tuple[np.ndarray, ...]) -> None:
    """The same convergence; the same solution to round-off where it converged. A pose that
    did not converge has no solution to compare: its last Newton iterate after 40 steps
    amplifies round-off (5e-9 rad once its inputs moved by 1e-16)."""
    converged = kernel[3]
    np.testing.assert_array_equal(source[3], converged)
    for got, want in zip(source[:3], kernel[:3], strict=True):  # m, rad: round-off only
        np.testing.assert_allclose(got[converged], want[converged], rtol=0, atol=1e-12,
                                   equal_nan=True)


def test_uncompiled_forward_is_the_kernel_pose_by_pose() -> None:
    """What a node runs (the kernel's source, no numba) solves as the compiled kernel does:
    the same convergence, mirrored or failed poses included, from home and from a previous
    solution, to round-off."""
    rng = np.random.default_rng(5)
    p, q = random_poses(400, rng)
    joints = kinematics.inverse(MECH, p, q)
    lengths = joints.lengths.copy()
    lengths[::7] *= rng.uniform(0.4, 1.8, (len(lengths[::7]), 3))  # many out of reach
    lengths[3] = 0.03  # no triangle at all
    for start in (kinematics.home_phis(MECH)[None], joints.phis + 1e-3):
        kernel, source = _both_runs(lengths, joints.thetas, start)
        assert kernel[3].sum() > 300 and not kernel[3].all()  # both kinds are exercised
        _assert_same(kernel, source)


@given(poses())
def test_uncompiled_forward_matches_the_kernel_over_the_workspace(
        pose: tuple[np.ndarray, np.ndarray]) -> None:
    p, q = pose
    joints = kinematics.inverse(MECH, p, q)
    _assert_same(*_both_runs(joints.lengths, joints.thetas, kinematics.home_phis(MECH)[None]))


def test_forward_runs_small_batches_uncompiled_without_numba_loaded() -> None:
    """The dispatch rule, in a fresh interpreter: one pose leaves numba out; a batch of
    COMPILED_BATCH poses loads it (a tool's batch), and once loaded every batch takes it."""
    code = (
        'import sys, numpy as np\n'
        'from positioning_cell.core import kinematics as k, compiled\n'
        'from positioning_cell.core.mechanism import Mechanism\n'
        'm = Mechanism.default()\n'
        'h = k.inverse(m, m.home_position[None], m.home_quaternion[None])\n'
        'assert k.forward(m, h.lengths, h.thetas).converged.all()\n'
        'print("one", "numba" in sys.modules)\n'
        'n = k.COMPILED_BATCH\n'
        'assert k.forward(m, np.repeat(h.lengths, n, 0), np.repeat(h.thetas, n, 0))'
        '.converged.all()\n'
        'print("batch", "numba" in sys.modules, compiled.loaded())\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=240, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split('\n')[:2] == ['one False', 'batch True True'], done.stdout
