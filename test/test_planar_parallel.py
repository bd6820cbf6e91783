"""Seed 002's planar 2-DOF over-constrained mechanism: every kinematic branch on the loop
equation (4 IK, 2 FK solutions), the degenerate configurations, the Jacobian and the links'
motion against finite differences, and the statics closed by compatibility (equilibrium,
compatibility, symmetry, Menabrea, the determinate limit, the rigid pseudo-inverse)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.linalg import null_space
from scipy.optimize import minimize_scalar

from positioning_cell.errors import InputError
from positioning_cell.mechanics import overconstrained as oc
from positioning_cell.mechanics import planar_parallel as pp

GEOMETRY = pp.PlanarParallel()
PARTS = pp.PlanarParts()
L = GEOMETRY.link_length
# The documented case (docs/howto/statics.md).
POSITION = np.array([0.05, 0.0])
FORCE = np.array([800.0, -1500.0])
MOMENT = 60.0

positions = st.tuples(st.floats(-0.19, 0.19), st.floats(-1.0, 1.0)).map(np.array)


def loop_closes(position: np.ndarray, heights: np.ndarray, tol: float = 1e-12) -> bool:
    """Seed 002 eq. 3 for all four links, from the geometry's fields (independent of the
    library's offsets): |t + A_i − (c_j, b_j) − S_i| = L."""
    guides = [-GEOMETRY.guide_offset] * 2 + [GEOMETRY.guide_offset] * 2
    for i in range(4):
        j = i // 2
        a = position + np.asarray(GEOMETRY.platform_joints[i])
        b = np.array([guides[i], heights[j]]) + np.asarray(GEOMETRY.slider_joints[i])
        if abs(np.linalg.norm(a - b) - L) > tol:
            return False
    return True


def contains(rows: np.ndarray, row: np.ndarray, tol: float = 1e-9) -> bool:
    return bool(np.any(np.all(np.abs(rows - row) < tol, axis=1)))


# -- kinematics ---------------------------------------------------------------------------------
@given(positions)
def test_four_inverse_and_two_forward_solutions_at_generic_positions(t: np.ndarray) -> None:
    """IK: exactly 4 distinct solutions, each closing the loop; FK of each contains t (seed
    002 §1.2); the hanging branch's FK has exactly 2 solutions and IK of each contains b."""
    ik = pp.inverse_kinematics(GEOMETRY, t)
    assert ik.heights.shape == (4, 2) and np.all(np.isfinite(ik.heights))
    assert ik.note == '' and np.all(ik.multiplicity == 1)
    assert len({tuple(np.round(h, 12)) for h in ik.heights}) == 4
    assert set(ik.modes) == {(a, b) for a in ('above', 'below') for b in ('above', 'below')}
    for heights in ik.heights:
        assert loop_closes(t, heights)
        fk = pp.forward_kinematics(GEOMETRY, heights)
        # Near a forward singularity (x ≈ 0 on a mixed branch) the FK is ill-conditioned (a
        # square root of a vanishing discriminant); at it the roots merge into one double root
        # within √TANGENCY·L of both.
        near = len(fk.positions) == 1 or np.linalg.norm(np.ptp(fk.positions, axis=0)) < 1e-4
        assert contains(fk.positions, t, 1e-6 if near else 1e-9)
    hanging = ik.hanging
    assert np.all(hanging > t[1])  # both sliders above the platform (d_y = 0 here)
    fk = pp.forward_kinematics(GEOMETRY, hanging)
    assert fk.positions.shape == (2, 2) and fk.modes == ('lower', 'upper')
    np.testing.assert_allclose(fk.hanging, t, atol=1e-12)
    for position in fk.positions:
        assert loop_closes(position, hanging)
        assert contains(pp.inverse_kinematics(GEOMETRY, position).heights, hanging)


@given(st.floats(-1.0, 1.0), st.floats(-0.3, 0.3))
def test_two_forward_solutions_for_generic_heights(b1: float, rise: float) -> None:
    """Circle centres at most √(0.8² + 0.3²) m apart, under 2L = 1.2 m: always 2 solutions,
    each closing the loop; IK of each contains the heights."""
    heights = np.array([b1, b1 + rise])
    fk = pp.forward_kinematics(GEOMETRY, heights)
    assert fk.positions.shape == (2, 2) and np.all(np.isfinite(fk.positions))
    assert np.linalg.norm(fk.positions[0] - fk.positions[1]) > 1e-6
    for position in fk.positions:
        assert loop_closes(position, heights)
        ik = pp.inverse_kinematics(GEOMETRY, position)
        assert len(ik.heights) == 4 and contains(ik.heights, heights)


def test_vectorised_hanging_branch_round_trip() -> None:
    rng = np.random.default_rng(2)
    t = np.column_stack([rng.uniform(-0.19, 0.19, 200), rng.uniform(-1.0, 1.0, 200)])
    b = pp.inverse_hanging(GEOMETRY, t)
    np.testing.assert_allclose(b, [pp.inverse_kinematics(GEOMETRY, p).hanging for p in t],
                               atol=1e-14)
    np.testing.assert_allclose(pp.forward_hanging(GEOMETRY, b), t, atol=1e-12)
    assert np.max(np.abs(pp.loop_residual(GEOMETRY, t, b))) < 1e-14


def test_degenerate_configurations_are_counted_and_named() -> None:
    # At x = 0.2 m the left links are horizontal: one double root for slider 1, so 2 solutions.
    ik = pp.inverse_kinematics(GEOMETRY, (0.2, 0.1))
    assert len(ik.heights) == 2 and ik.multiplicity.tolist() == [2.0, 2.0]
    assert [m[0] for m in ik.modes] == ['level', 'level'] and 'slider 1' in ik.note
    assert all(loop_closes(np.array([0.2, 0.1]), h) for h in ik.heights)
    assert pp.singularity(GEOMETRY, (0.2, 0.1)).inverse == (True, False)
    assert 'inverse singularity' in pp.singularity(GEOMETRY, (0.2, 0.1)).describe()
    with pytest.raises(InputError, match='inverse singularity'):
        pp.jacobian(GEOMETRY, (0.2, 0.1))
    # Beyond: the left links cannot reach.
    with pytest.raises(InputError, match=r'slider 1 are 0\.65 m .* no inverse kinematics'):
        pp.inverse_kinematics(GEOMETRY, (0.25, 0.0))
    with pytest.raises(InputError, match='slider 2'):
        pp.inverse_hanging(GEOMETRY, [[0.0, 0.0], [-0.3, 0.0]])
    # Circle centres exactly 2L apart: the left and right links collinear, one double solution.
    rise = np.sqrt((2 * L) ** 2 - 0.8**2)
    fk = pp.forward_kinematics(GEOMETRY, (0.0, rise))
    assert fk.modes == ('collinear',) and fk.multiplicity.tolist() == [2.0]
    np.testing.assert_allclose(fk.positions[0], [0.0, rise / 2], atol=1e-12)
    assert 'forward singularity' in fk.note
    with pytest.raises(InputError, match='no forward kinematics'):
        pp.forward_kinematics(GEOMETRY, (0.0, 1.0))
    # The lower intersection with the left slider below its platform joints: not the machine's.
    with pytest.raises(InputError, match='slider 1 would be below'):
        pp.forward_hanging(GEOMETRY, [(0.0, 0.8)])


def test_geometry_is_checked() -> None:
    with pytest.raises(InputError, match='no parallelogram'):
        pp.PlanarParallel(slider_joints=((0.0, 0.05), (0.0, -0.06), (0.0, 0.05), (0.0, -0.05)))
    with pytest.raises(InputError, match='link_length'):
        pp.PlanarParallel(link_length=float('nan'))
    with pytest.raises(InputError, match=r'2L = 0\.8'):
        pp.PlanarParallel(link_length=0.4)
    with pytest.raises(InputError, match='single link'):
        pp.PlanarParallel(platform_joints=((-0.1, 0.0),) * 2 + ((0.1, 0.0),) * 2,
                          slider_joints=((0.0, 0.0),) * 4)
    with pytest.raises(InputError, match='link_sections'):
        pp.PlanarParts(link_sections=(1e-3, 1e-3, 0.0, 1e-3))


@settings(max_examples=40)
@given(positions)
def test_jacobian_against_finite_differences_on_every_branch(t: np.ndarray) -> None:
    """ḃ = J·ṫ (seed 002 eq. 10): J against central differences of each IK branch."""
    h = 1e-6
    ik = pp.inverse_kinematics(GEOMETRY, t)
    for heights, modes in zip(ik.heights, ik.modes, strict=True):
        numeric = np.empty((2, 2))
        for k in range(2):
            step = np.eye(2)[k] * h
            ends = []
            for sign in (1, -1):
                other = pp.inverse_kinematics(GEOMETRY, t + sign * step)
                ends.append(other.heights[other.modes.index(modes)])
            numeric[:, k] = (ends[0] - ends[1]) / (2 * h)
        np.testing.assert_allclose(pp.jacobian(GEOMETRY, t, heights), numeric, rtol=1e-6,
                                   atol=1e-6)


def test_forward_singularity_makes_the_jacobian_singular() -> None:
    """At x = 0 with one slider above and one below, the left and right links are collinear:
    det J = 0 (an FK double root), and the statics cannot be solved (rank 2 < 3)."""
    ik = pp.inverse_kinematics(GEOMETRY, (0.0, 0.0))
    heights = ik.heights[ik.modes.index(('above', 'below'))]
    sing = pp.singularity(GEOMETRY, (0.0, 0.0), heights)
    assert sing.forward and not any(sing.inverse)
    assert 'forward singularity' in sing.describe()
    assert abs(np.linalg.det(pp.jacobian(GEOMETRY, (0.0, 0.0), heights))) < 1e-12
    assert len(pp.forward_kinematics(GEOMETRY, heights).positions) == 1
    with pytest.raises(InputError, match=r'rank 2 < 3 \(planar\)'):
        pp.solve_statics(GEOMETRY, PARTS, (0.0, 0.0), heights=heights)
    regular = pp.singularity(GEOMETRY, POSITION)
    assert regular.describe() == 'regular' and regular.determinant < 0


def test_link_motion_against_finite_differences() -> None:
    """Slider rates, link angular rates and centroid accelerations (seed 002 eqs. 10-18)
    against central differences of the hanging branch along t(s) = t0 + v·s + a·s²/2."""
    t0, v, a = np.array([0.06, -0.1]), np.array([0.3, -0.2]), np.array([-1.5, 2.0])
    motion = pp.link_motion(GEOMETRY, t0, v, a)
    h = 1e-4
    s = np.array([-h, 0.0, h])
    t = t0 + s[:, None] * v + 0.5 * s[:, None] ** 2 * a
    b = pp.inverse_hanging(GEOMETRY, t)
    vectors = pp.link_vectors(GEOMETRY, t, b)
    angles = np.unwrap(np.arctan2(vectors[..., 1], vectors[..., 0]), axis=0)
    guides = np.array([-GEOMETRY.guide_offset] * 2 + [GEOMETRY.guide_offset] * 2)
    joints_b = (np.stack([np.broadcast_to(guides, (3, 4)), b[:, [0, 0, 1, 1]]], axis=-1)
                + np.asarray(GEOMETRY.slider_joints))
    centroids = joints_b + 0.5 * vectors

    def rate(x: np.ndarray) -> np.ndarray:
        return (x[2] - x[0]) / (2 * h)

    def rate2(x: np.ndarray) -> np.ndarray:
        return (x[2] - 2 * x[1] + x[0]) / h**2

    np.testing.assert_allclose(motion.slider_velocity, rate(b), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(motion.slider_acceleration, rate2(b), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(motion.angular_velocity, rate(angles), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(motion.angular_acceleration, rate2(angles), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(motion.centroid_acceleration, rate2(centroids), rtol=1e-5,
                               atol=1e-5)


# -- statics ------------------------------------------------------------------------------------
def link_loads(result: pp.PlanarStatics, parts: pp.PlanarParts,
               velocity: np.ndarray, acceleration: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each link's weight + inertia force (4, 2) and angular acceleration (4,)."""
    motion = pp.link_motion(GEOMETRY, result.position, velocity, acceleration)
    masses = np.asarray(parts.link_masses)
    return (masses[:, None] * (np.asarray(parts.gravity) - motion.centroid_acceleration),
            motion.angular_acceleration)


@pytest.mark.parametrize('moving', [False, True], ids=['static', 'accelerating'])
def test_statics_balances_every_body_and_closes_compatibility(moving: bool) -> None:
    """Platform, links and sliders each in equilibrium (seed 002 eqs. 19-24, d'Alembert),
    computed here from the returned joint forces; the links' elongations those of the platform
    error (eq. 28); the axial forces at the two ends differ by the distributed load (eq. 29)."""
    v = np.array([0.2, 0.1]) if moving else np.zeros(2)
    a = np.array([0.5, -1.0]) if moving else np.zeros(2)
    misfit = np.array([10e-6, 0.0, -5e-6, 0.0])
    parts = pp.PlanarParts(link_sections=(1.0e-3, 0.8e-3, 1.2e-3, 1.0e-3))
    r = pp.solve_statics(GEOMETRY, parts, POSITION, FORCE, MOMENT, v, a, misfit)
    assert r.equilibrium_residual < 1e-14 and r.compatibility_residual < 1e-12
    g = np.asarray(parts.gravity)
    joints = np.asarray(GEOMETRY.platform_joints)
    # Platform.
    weight = parts.platform_mass * (g - a)
    np.testing.assert_allclose(FORCE + weight + r.platform_joint_forces.sum(axis=0), 0.0,
                               atol=1e-9)
    on_platform = r.platform_joint_forces
    moments = joints[:, 0] * on_platform[:, 1] - joints[:, 1] * on_platform[:, 0]
    assert abs(MOMENT + moments.sum()) < 1e-9
    # Links: forces, and moments about the slider joint B_i.
    loads, alpha = link_loads(r, parts, v, a)
    on_link = -on_platform - r.slider_joint_forces + loads
    np.testing.assert_allclose(on_link, 0.0, atol=1e-9)
    u = r.directions
    inertia = np.asarray(parts.link_masses) * L**2 / 12
    about_b = (L * (u[:, 1] * on_platform[:, 0] - u[:, 0] * on_platform[:, 1])
               + 0.5 * L * (u[:, 0] * loads[:, 1] - u[:, 1] * loads[:, 0]) - inertia * alpha)
    np.testing.assert_allclose(about_b, 0.0, atol=1e-9)
    # The axial force at A_i is the tension f_i; at B_i it adds the distributed load.
    np.testing.assert_allclose(np.sum(-on_platform * u, axis=1), r.forces,
                               atol=1e-9)
    np.testing.assert_allclose(r.forces_at_sliders - r.forces, r.distributed * L, atol=1e-9)
    # Compatibility (eq. 28): J_e·δx = ΔL + misfit.
    np.testing.assert_allclose(pp.error_jacobian(GEOMETRY, POSITION) @ r.deflection,
                               r.elongations + misfit, rtol=1e-9, atol=1e-15)
    # The whole machine: drives and guides balance every weight, inertia and the load.
    motion = pp.link_motion(GEOMETRY, POSITION, v, a)
    sliders = np.asarray(parts.slider_masses)[:, None] * (
        g - motion.slider_acceleration[:, None] * np.array([0.0, 1.0]))
    total = FORCE + weight + loads.sum(axis=0) + sliders.sum(axis=0)
    np.testing.assert_allclose([r.guide_forces.sum(), r.drive_forces.sum()], -total, atol=1e-9)


def test_documented_case() -> None:
    """The docs' numbers (docs/howto/statics.md, static): the sliders at 0.3969 and 0.4873 m,
    tensions
    857 / 1561 / 1144 / 596 N, the platform 1.7 µm left, 4.6 µm down and turned 26.8 µrad; link 4
    at half section, and link 1 20 µm too long."""
    r = pp.solve_statics(GEOMETRY, PARTS, POSITION, FORCE, MOMENT)
    np.testing.assert_allclose(r.heights, [0.396863, 0.487340], atol=1e-6)
    np.testing.assert_allclose(r.forces, [857.2, 1561.2, 1143.6, 596.1], atol=0.1)
    np.testing.assert_allclose(r.deflection, [-1.728e-6, -4.567e-6, 2.682e-5], rtol=1e-3)
    np.testing.assert_allclose(r.drive_forces, [2058.3, 1882.0], atol=0.1)
    # Equal stiffness, no misfit: the compatible forces are the minimum-norm ones.
    np.testing.assert_allclose(r.pseudo_inverse, r.forces, rtol=1e-10)
    soft = pp.PlanarParts(link_sections=(1.0e-3, 1.0e-3, 1.0e-3, 0.5e-3))
    np.testing.assert_allclose(pp.solve_statics(GEOMETRY, soft, POSITION, FORCE, MOMENT).forces,
                               [970.8, 1447.6, 1289.7, 450.0], atol=0.1)
    long = pp.solve_statics(GEOMETRY, PARTS, POSITION, FORCE, MOMENT,
                            misfit=(20e-6, 0.0, 0.0, 0.0))
    np.testing.assert_allclose(long.forces, [-462.0, 2880.4, -552.5, 2292.2], atol=0.1)
    np.testing.assert_allclose(long.deflection, [24.38e-6, -6.70e-6, -139.3e-6], rtol=2e-3)
    np.testing.assert_allclose(long.pseudo_inverse, r.forces, rtol=1e-10)


def test_pseudo_inverse_ignores_stiffness_and_misfit() -> None:
    """The rigid pseudo-inverse satisfies equilibrium but not compatibility once the links
    differ in stiffness or one is made 20 µm long; the compatible forces follow both."""
    soft = pp.PlanarParts(link_sections=(1.0e-3, 1.0e-3, 1.0e-3, 0.5e-3))
    cases = [pp.solve_statics(GEOMETRY, soft, POSITION, FORCE, MOMENT),
             pp.solve_statics(GEOMETRY, PARTS, POSITION, FORCE, MOMENT,
                              misfit=(20e-6, 0.0, 0.0, 0.0))]
    for r in cases:
        assert oc.equilibrium_residual(r.wrenches, r.pseudo_inverse, r.load) < 1e-14
        assert oc.compatibility_residual(r.wrenches, r.stiffness, r.pseudo_inverse,
                                         r.initial) > 0.05
        assert np.max(np.abs(r.pseudo_inverse - r.forces)) > 50.0


def test_symmetric_load_gives_equal_mirror_pairs() -> None:
    """Platform centred, load on the axis of symmetry: links 1, 3 (upper) and 2, 4 (lower)
    carry equal tensions pairwise, the platform only sinks, the drives share equally; upper and
    lower links differ here (sections 1.0 and 0.6 cm²)."""
    parts = pp.PlanarParts(link_sections=(1.0e-3, 0.6e-3, 1.0e-3, 0.6e-3))
    r = pp.solve_statics(GEOMETRY, parts, (0.0, 0.1), (0.0, -2000.0), 0.0,
                         acceleration=(0.0, 1.5))
    np.testing.assert_allclose(r.forces[[0, 1]], r.forces[[2, 3]], rtol=1e-12)
    assert abs(r.forces[0] - r.forces[1]) > 100.0
    assert abs(r.deflection[0]) < 1e-15 and abs(r.deflection[2]) < 1e-14
    np.testing.assert_allclose(r.drive_forces[0], r.drive_forces[1], rtol=1e-12)
    np.testing.assert_allclose(r.guide_forces[0], -r.guide_forces[1], rtol=1e-12)


def complementary_energy(r: pp.PlanarStatics, parts: pp.PlanarParts, forces: np.ndarray,
                         misfit: np.ndarray) -> float:
    """Σ ∫₀ᴸ N_i(x)²/(2·E·S_i) dx + Σ f_i·e_i with N_i(x) = f_i + w_i·(L − x) (seed 002 eq. 29),
    integrated numerically."""
    total = 0.0
    for f, w, s, e in zip(forces, r.distributed, parts.link_sections, misfit, strict=True):
        rigidity = parts.youngs_modulus * s
        total += quad(lambda x, f=f, w=w, ea=rigidity: (f + w * (L - x)) ** 2 / (2 * ea),
                      0.0, L)[0] + f * e
    return total


def test_compatible_forces_minimise_complementary_energy() -> None:
    """Menabrea: among the tensions in equilibrium f = f_p + z·ν (ν the self-stress), the
    compatible ones minimise the complementary energy, distributed loads and misfit included;
    with equal stiffness and no distributed load that is the minimum norm, the pseudo-inverse."""
    misfit = np.array([0.0, 15e-6, 0.0, 0.0])
    parts = pp.PlanarParts(link_sections=(1.0e-3, 0.7e-3, 1.3e-3, 1.0e-3),
                           link_masses=(8.0, 6.0, 9.0, 7.0))
    r = pp.solve_statics(GEOMETRY, parts, POSITION, FORCE, MOMENT, misfit=misfit)
    particular = r.pseudo_inverse
    nu = null_space(r.wrenches.T)[:, 0]
    best = minimize_scalar(lambda z: complementary_energy(r, parts, particular + z * nu, misfit),
                           bracket=(-1000.0, 1000.0), options={'xtol': 1e-12})
    np.testing.assert_allclose(particular + best.x * nu, r.forces, rtol=1e-6, atol=1e-3)
    massless = pp.PlanarParts(link_masses=(0.0,) * 4)
    light = pp.solve_statics(GEOMETRY, massless, POSITION, FORCE, MOMENT)
    np.testing.assert_allclose(light.forces, light.pseudo_inverse, rtol=1e-10)


def test_a_near_zero_stiffness_fourth_link_gives_the_determinate_answer() -> None:
    """Link 4 at 1e-9 of the others' section: it carries only its own weight's axial share,
    half at each end (mean tension 0), and links 1-3 the statically determinate answer."""
    parts = pp.PlanarParts(link_sections=(1.0e-3, 1.0e-3, 1.0e-3, 1.0e-12))
    r = pp.solve_statics(GEOMETRY, parts, POSITION, FORCE, MOMENT, velocity=(0.1, 0.0),
                         acceleration=(0.3, 0.4))
    own = -0.5 * r.distributed[3] * L
    assert abs(r.forces[3] - own) < 1e-8 * np.max(np.abs(r.forces))
    determinate = np.linalg.solve(r.wrenches[:3].T, -(r.load + r.wrenches[3] * own))
    np.testing.assert_allclose(r.forces[:3], determinate, rtol=1e-7)
    massless = pp.PlanarParts(link_masses=(0.0,) * 4, link_sections=parts.link_sections)
    light = pp.solve_statics(GEOMETRY, massless, POSITION, FORCE, MOMENT)
    assert abs(light.forces[3]) < 1e-8 * np.max(np.abs(light.forces))
    np.testing.assert_allclose(light.forces[:3], np.linalg.solve(light.wrenches[:3].T,
                                                                 -light.load), rtol=1e-7)


def test_bad_statics_input() -> None:
    with pytest.raises(InputError, match='misfit'):
        pp.solve_statics(GEOMETRY, PARTS, POSITION, misfit=(0.0, 0.0, 0.0))
    with pytest.raises(InputError, match='force'):
        pp.solve_statics(GEOMETRY, PARTS, POSITION, force=(float('nan'), 0.0))
    with pytest.raises(InputError, match='no inverse kinematics'):
        pp.solve_statics(GEOMETRY, PARTS, (0.3, 0.0))
    with pytest.raises(InputError, match='do not close the loop'):
        pp.solve_statics(GEOMETRY, PARTS, POSITION, heights=(0.4, 0.4))
