"""Seed 002's planar 2-DOF over-constrained parallel mechanism (Jiang, Li & Wang 2013, §1-3): its
geometry, forward and inverse kinematics with every branch, the velocity Jacobian and its
singularities, the links' motion (eqs. 7-18) and the statics closed by deformation
compatibility (eqs. 19-29).

Frames and units (seed 002 §1.2): base frame {O} at the midpoint of C1C2, x along C1C2 (to the
right), y along the guides (up), z = x × y out of the plane; SI (m, N, rad, kg, s). Two
parallelograms keep the platform N from rotating: its frame {T} has its origin at the platform
centre t = (x, y) and the base axes (R = I, seed 002 eq. 1). Slider P_j (j = 1 left, 2 right)
runs on the vertical guide x = c_j (c_1 = −c, c_2 = +c) at height b_j, the input. Link i
(links 1, 2 on slider 1, links 3, 4 on slider 2, all of length L) joins the slider joint
B_i = (c_j, b_j) + S_i to the platform joint t + A_i; the loop (seed 002 eq. 3, the paper's
b_i = b_j + S_iy) is

    t + A_i = c_j + b_j·e2 + S_i + L·l_i,      l_i the unit vector from B_i to A_i.

The pairs are parallelograms: A_1 − S_1 = A_2 − S_2 and A_3 − S_3 = A_4 − S_4, so the two
links of a slider are parallel and the platform centre runs, with slider j locked, on the circle
of radius L about P_j = (c_j, b_j) + S_i − A_i. Hence (seed 002 §1.2) the inverse kinematics
has 4 solutions (each slider above or below its platform joints) and the forward kinematics 2
(the circles' intersections, below or above the line P_1P_2). The mechanical constraints of the
machine pick one of each: the **hanging branch**, the platform below both sliders (every l_i
points down, l_iy < 0; the lower intersection).

Assumed numbers (the paper's Table 1 is missing from our text), plausible for the parallel part
of a hybrid machine tool and all parameters: guides 1.0 m apart (c = 0.5 m), links
L = 0.6 m, platform joints 0.1 m left and right of the centre, the two links of a pair 0.1 m
apart vertically; steel links (E = 210 GPa) of a Ø60 × 6 mm tube, S = 1.0e-3 m², 4.71 kg each
(ρ = 7850 kg/m³), axial stiffness E·S/L = 3.5e8 N/m; a 150 kg platform with its spindle head,
40 kg sliders; gravity −9.80665 m/s² along y. The reachable workspace is |x| ≤ 0.2 m (any
y within the sliders' strokes, which are not modelled).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.mechanics import overconstrained as oc

FloatArray = NDArray[np.float64]
Pair = tuple[float, float]
Four = tuple[Pair, Pair, Pair, Pair]

#: Standard gravity, m/s².
STANDARD_GRAVITY = 9.80665

#: The slider (0: left, 1: right) each link (0..3 for links 1..4) hangs from.
SLIDER_OF_LINK = (0, 0, 1, 1)

#: Within this fraction of L² of tangency a pair of roots is one double root (which then lies
#: within √TANGENCY·L of each root it merges: 0.06 µm for L = 0.6 m).
TANGENCY = 1e-14

#: |l_y| (inverse) or |l_1 × l_3| (forward) below this counts as singular.
SINGULAR = 1e-9

#: Loop residual (fraction of L) above which a solution is refused.
LOOP_TOLERANCE = 1e-9

_E2 = np.array([0.0, 1.0])


def _finite(value: ArrayLike, shape: tuple[int, ...], name: str, unit: str) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f'{name} = {value!r}: expected finite values of shape {shape} ({unit})')
    return arr


def _pairs(value: ArrayLike, name: str, unit: str) -> FloatArray:
    """Finite (..., 2) values, at least one pair."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim < 1 or arr.shape[-1] != 2 or not np.all(np.isfinite(arr)):
        raise InputError(f'{name} = {value!r}: expected finite (..., 2) values ({unit})')
    return arr


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """z component of a × b for (..., 2) vectors."""
    out: FloatArray = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _normal(u: FloatArray) -> FloatArray:
    """e3 × u for (..., 2) vectors: u turned by +90°."""
    return np.stack([-u[..., 1], u[..., 0]], axis=-1)


# -- geometry -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanarParallel:
    """Geometry of seed 002's 2-DOF over-constrained planar mechanism (m; frames in the module
    docstring): guides at x = ∓``guide_offset`` (c), ``link_length`` L, the platform joints
    A_1..A_4 (platform frame, about the platform centre) and the slider joints S_1..S_4
    (about the slider's point on its guide at height b_j); links 1, 2 on the left slider,
    3, 4 on the right. Defaults: the assumed machine of the module docstring."""

    guide_offset: float = 0.5
    link_length: float = 0.6
    platform_joints: Four = ((-0.1, 0.05), (-0.1, -0.05), (0.1, 0.05), (0.1, -0.05))
    slider_joints: Four = ((0.0, 0.05), (0.0, -0.05), (0.0, 0.05), (0.0, -0.05))

    def __post_init__(self) -> None:
        for name in ('guide_offset', 'link_length'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise InputError(f'{name} = {value!r}: must be finite and > 0 (m)')
        a = _finite(self.platform_joints, (4, 2), 'platform_joints', 'm')
        s = _finite(self.slider_joints, (4, 2), 'slider_joints', 'm')
        d = a - s - np.array([[-self.guide_offset, 0.0]] * 2 + [[self.guide_offset, 0.0]] * 2)
        length = self.link_length
        for first, side in ((0, 'left'), (2, 'right')):
            gap = float(np.linalg.norm(d[first] - d[first + 1]))
            if gap > 1e-9 * length:
                raise InputError(
                    f'links {first + 1} and {first + 2} ({side} slider) are no parallelogram: '
                    f'A − S = {d[first].tolist()} and {d[first + 1].tolist()} differ by {gap:.3g} '
                    'm')
            if np.linalg.norm(a[first] - a[first + 1]) < 1e-9 * length:
                raise InputError(f'links {first + 1} and {first + 2} share their platform joint '
                                 f'{a[first].tolist()}: the pair is a single link')
        span = float(d[0, 0] - d[2, 0])
        if not 0.0 < span < 2.0 * length:
            raise InputError(
                f'the circles the platform centre runs on are {span:.6g} m apart along x '
                f'(P_2x − P_1x); it must lie in (0, 2L = {2.0 * length:.6g}) m for the '
                'mechanism to assemble with the left slider on the left')

    @property
    def offsets(self) -> FloatArray:
        """d_j = A_i − S_i − c_j (2, 2) (m) of each slider's links (seed 002 eq. 3 rearranged:
        L·l_i = t + d_j − b_j·e2)."""
        a = np.asarray(self.platform_joints, dtype=float)[[0, 2]]
        s = np.asarray(self.slider_joints, dtype=float)[[0, 2]]
        out: FloatArray = a - s - np.array([[-self.guide_offset, 0.0], [self.guide_offset, 0.0]])
        return out

    @property
    def circle_centres(self) -> FloatArray:
        """P_j (2, 2) (m) at zero slider heights: with slider j at height b_j the platform
        centre runs on the circle of radius L about P_j + b_j·e2."""
        centres: FloatArray = -self.offsets
        return centres


@dataclass(frozen=True)
class PlanarParts:
    """Masses and material of seed 002's mechanism (SI; assumed, see the module docstring).

    platform_mass (kg) and platform_centre_of_mass (m, platform frame); per link its mass
    link_masses (kg) and section link_sections (m²), all of one material of Young's modulus
    youngs_modulus (Pa); each link a uniform slender bar (centre of mass at L/2, inertia
    m·L²/12 about it: the uniform loads of seed 002 eq. 29); slider_masses (kg); gravity
    (m/s², base frame)."""

    platform_mass: float = 150.0
    platform_centre_of_mass: Pair = (0.0, 0.0)
    link_masses: tuple[float, float, float, float] = (4.71, 4.71, 4.71, 4.71)
    link_sections: tuple[float, float, float, float] = (1.0e-3, 1.0e-3, 1.0e-3, 1.0e-3)
    youngs_modulus: float = 2.1e11
    slider_masses: Pair = (40.0, 40.0)
    gravity: Pair = (0.0, -STANDARD_GRAVITY)

    def __post_init__(self) -> None:
        _finite(self.platform_centre_of_mass, (2,), 'platform_centre_of_mass', 'm')
        _finite(self.gravity, (2,), 'gravity', 'm/s^2')
        checks = (('platform_mass', self.platform_mass, (), 'kg', False),
                  ('link_masses', self.link_masses, (4,), 'kg', False),
                  ('link_sections', self.link_sections, (4,), 'm^2', True),
                  ('youngs_modulus', self.youngs_modulus, (), 'Pa', True),
                  ('slider_masses', self.slider_masses, (2,), 'kg', False))
        for name, value, shape, unit, positive in checks:
            arr = _finite(value, shape, name, unit)
            if np.any(arr <= 0.0) if positive else np.any(arr < 0.0):
                raise InputError(f'{name} = {value!r}: must be {">" if positive else ">="} 0 '
                                 f'({unit})')

    def axial_stiffness(self, geometry: PlanarParallel) -> FloatArray:
        """E·S_i/L (4,) (N/m) of the links."""
        return self.youngs_modulus * np.asarray(self.link_sections) / geometry.link_length


# -- loop equation ------------------------------------------------------------------------------
def link_vectors(geometry: PlanarParallel, position: ArrayLike,
                 heights: ArrayLike) -> FloatArray:
    """L·l_i (..., 4, 2) (m, base frame) from the slider joint B_i to the platform joint of
    each link, for platform positions (..., 2) and slider heights (..., 2) (m), seed 002 eq. 3:
    L·l_i = t + A_i − c_j − b_j·e2 − S_i. Their lengths are L when the loop closes."""
    t = _pairs(position, 'position', 'm')
    b = _pairs(heights, 'heights', 'm')
    d = geometry.offsets[list(SLIDER_OF_LINK)]
    out: FloatArray = (t[..., None, :] + d
                       - b[..., list(SLIDER_OF_LINK), None] * _E2)
    return out


def loop_residual(geometry: PlanarParallel, position: ArrayLike,
                  heights: ArrayLike) -> FloatArray:
    """|L·l_i| − L (..., 4) (m) of every link: 0 where the loop of seed 002 eq. 3 closes."""
    out: FloatArray = (np.linalg.norm(link_vectors(geometry, position, heights), axis=-1)
                       - geometry.link_length)
    return out


def _verified(geometry: PlanarParallel, position: ArrayLike, heights: ArrayLike,
              what: str) -> FloatArray:
    """Max |loop residual| per solution (m); ConvergenceError if one does not close."""
    residual: FloatArray = np.max(np.abs(loop_residual(geometry, position, heights)), axis=-1)
    if np.any(residual > LOOP_TOLERANCE * geometry.link_length):
        raise ConvergenceError(f'{what}: a solution misses the loop by {float(residual.max())} m')
    return residual


# -- inverse kinematics -------------------------------------------------------------------------
class InverseSolutions(NamedTuple):
    """Every slider-height pair (n, 2) (m) that puts the platform centre at ``position``: n = 4
    at a generic position, fewer where a slider's links are perpendicular to its guide (a double
    root). ``modes`` per solution and slider: 'above' (the slider joint above the platform joint,
    l_y < 0), 'below', or 'level' (the double root); ``multiplicity`` (n,) each solution's root
    multiplicity (4 in all); ``residual`` (n,) its largest loop residual (m, seed 002 eq. 3);
    ``note`` the degeneracy in words ('' when generic)."""

    position: FloatArray
    heights: FloatArray
    modes: tuple[tuple[str, str], ...]
    multiplicity: FloatArray
    residual: FloatArray
    note: str

    @property
    def hanging(self) -> FloatArray:
        """The solution of the machine's branch (both sliders above: the platform hangs)."""
        for heights, modes in zip(self.heights, self.modes, strict=True):
            if all(mode in ('above', 'level') for mode in modes):
                return np.asarray(heights, dtype=float)
        raise InputError(f'position {self.position.tolist()}: no hanging solution')


def _unreachable(j: int, dx: float, length: float, position: object) -> InputError:
    return InputError(
        f'position {position}: the platform joints of slider {j + 1} are {abs(dx):.6g} m from '
        f'its guide horizontally, beyond the link length {length:.6g} m: no inverse kinematics')


def inverse_kinematics(geometry: PlanarParallel, position: ArrayLike) -> InverseSolutions:
    """All slider heights b = (b_1, b_2) (m) for the platform centre at ``position`` (2,) (m,
    base frame), seed 002 eq. 3: b_j = t_y + d_jy ± √(L² − (t_x + d_jx)²), each slider above
    (+) or below (−) its platform joints; 4 solutions, each checked on the loop of all four
    links. A slider whose links would have to be perpendicular to its guide (tangency, within
    :data:`TANGENCY`·L²) has one double root; InputError names the slider that cannot reach."""
    t = _finite(position, (2,), 'position', 'm')
    d, length = geometry.offsets, geometry.link_length
    per_slider: list[tuple[tuple[float, str, int], ...]] = []
    notes = []
    for j in range(2):
        dx = float(t[0] + d[j, 0])
        disc = length * length - dx * dx
        level = float(t[1] + d[j, 1])
        if disc < -TANGENCY * length * length:
            raise _unreachable(j, dx, length, t.tolist())
        if disc <= TANGENCY * length * length:
            per_slider.append(((level, 'level', 2),))
            notes.append(f'slider {j + 1}: its links are perpendicular to its guide (inverse '
                         'singularity, workspace boundary): one double root')
        else:
            root = math.sqrt(disc)
            per_slider.append(((level + root, 'above', 1), (level - root, 'below', 1)))
    combos = list(itertools.product(*per_slider))
    heights = np.array([[c[0][0], c[1][0]] for c in combos])
    residual = _verified(geometry, t, heights, 'inverse kinematics')
    return InverseSolutions(t, heights, tuple((c[0][1], c[1][1]) for c in combos),
                            np.array([float(c[0][2] * c[1][2]) for c in combos]), residual,
                            '; '.join(notes))


def inverse_hanging(geometry: PlanarParallel, position: ArrayLike) -> FloatArray:
    """Slider heights (..., 2) (m) of the hanging branch (both sliders above their platform
    joints) for platform positions (..., 2) (m), vectorised; InputError names the first
    position a slider cannot reach."""
    t = _pairs(position, 'position', 'm')
    d, length = geometry.offsets, geometry.link_length
    dx = t[..., None, 0] + d[:, 0]
    disc = length * length - dx * dx
    bad = disc < -TANGENCY * length * length
    if np.any(bad):
        index = np.argwhere(bad)[0]
        raise _unreachable(int(index[-1]), float(dx[tuple(index)]), length,
                           t[tuple(index[:-1])].tolist())
    out: FloatArray = t[..., None, 1] + d[:, 1] + np.sqrt(np.maximum(disc, 0.0))
    return out


# -- forward kinematics -------------------------------------------------------------------------
class ForwardSolutions(NamedTuple):
    """Every platform position (n, 2) (m) for slider ``heights``: n = 2 generic, 1 where the two
    circles touch (the left and right links collinear: a forward singularity). ``modes``:
    'lower' / 'upper' (below / above the line P_1P_2 through the circles' centres; the machine
    runs 'lower'), or 'collinear' (the double root); ``multiplicity`` (n,) and ``residual`` (n,)
    (m) as in :class:`InverseSolutions`; ``note`` the degeneracy in words."""

    heights: FloatArray
    positions: FloatArray
    modes: tuple[str, ...]
    multiplicity: FloatArray
    residual: FloatArray
    note: str

    @property
    def hanging(self) -> FloatArray:
        """The 'lower' (or double) solution: the machine's assembly mode."""
        return np.asarray(self.positions[0], dtype=float)


def _circles(geometry: PlanarParallel,
             b: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Centres P_j (..., 2, 2), their midpoint, the unit normal n = e3 × (P_2 − P_1)/D and the
    squared half-chord L² − D²/4 (m²)."""
    centres = b[..., :, None] * _E2 - geometry.offsets
    delta = centres[..., 1, :] - centres[..., 0, :]
    dist = np.linalg.norm(delta, axis=-1)
    normal = _normal(delta) / dist[..., None]
    half = geometry.link_length**2 - 0.25 * dist**2
    return centres, 0.5 * (centres[..., 0, :] + centres[..., 1, :]), normal, half


def _too_far(b: object, half: float, length: float) -> InputError:
    dist = 2.0 * math.sqrt(length * length - half)
    return InputError(
        f'slider heights {b}: the platform centre must lie L = {length:.6g} m from two circle '
        f'centres {dist:.6g} m apart, beyond 2L = {2.0 * length:.6g} m: no forward kinematics')


def forward_kinematics(geometry: PlanarParallel, heights: ArrayLike) -> ForwardSolutions:
    """All platform positions t (m, base frame) for slider heights (2,) (m), seed 002 eq. 3:
    the intersections of the circles of radius L about P_1 and P_2 (t = M ∓ h·n, M the
    midpoint, h = √(L² − D²/4)); 2 solutions, each checked on the loop of all four links. Tangent
    circles (within :data:`TANGENCY`·L²) give one double solution; InputError when they do not
    meet."""
    b = _finite(heights, (2,), 'heights', 'm')
    length = geometry.link_length
    _, mid, normal, half = _circles(geometry, b)
    half_f = float(half)
    if half_f < -TANGENCY * length * length:
        raise _too_far(b.tolist(), half_f, length)
    if half_f <= TANGENCY * length * length:
        positions = mid[None]
        modes: tuple[str, ...] = ('collinear',)
        multiplicity = np.array([2.0])
        note = ('the left and right links are collinear (forward singularity): one double '
                'solution')
    else:
        h = math.sqrt(half_f)
        positions = np.stack([mid - h * normal, mid + h * normal])
        modes, multiplicity, note = ('lower', 'upper'), np.array([1.0, 1.0]), ''
    residual = _verified(geometry, positions, np.broadcast_to(b, positions.shape),
                         'forward kinematics')
    return ForwardSolutions(b, positions, modes, multiplicity, residual, note)


def forward_hanging(geometry: PlanarParallel, heights: ArrayLike) -> FloatArray:
    """Platform positions (..., 2) (m) of the hanging branch for slider heights (..., 2) (m),
    vectorised: the lower intersection, refused (InputError) where the circles do not meet or
    where a slider would end up below its platform joints (outside the machine's branch)."""
    b = _pairs(heights, 'heights', 'm')
    length = geometry.link_length
    centres, mid, normal, half = _circles(geometry, b)
    bad = half < -TANGENCY * length * length
    if np.any(bad):
        index = tuple(np.argwhere(np.atleast_1d(bad))[0])
        raise _too_far(np.atleast_2d(b)[index].tolist(), float(np.atleast_1d(half)[index]),
                       length)
    t: FloatArray = mid - np.sqrt(np.maximum(half, 0.0))[..., None] * normal
    rise = t[..., None, 1] - centres[..., 1]
    if np.any(rise > SINGULAR * length):
        index = tuple(np.argwhere(np.atleast_2d(rise) > SINGULAR * length)[0])
        raise InputError(f'slider heights {np.atleast_2d(b)[index[:-1]].tolist()}: slider '
                         f'{index[1] + 1} would be below its platform joints: outside the '
                         'hanging branch')
    return t


# -- velocity, singularity, link motion (seed 002 eqs. 7-18) -----------------------------------
def _configuration(geometry: PlanarParallel, position: ArrayLike,
                   heights: ArrayLike | None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position (2,), heights (2,) (the hanging ones if None) and unit link directions (4, 2),
    the loop checked."""
    t = _finite(position, (2,), 'position', 'm')
    b = (inverse_hanging(geometry, t) if heights is None
         else _finite(heights, (2,), 'heights', 'm'))
    vectors = link_vectors(geometry, t, b)
    residual = float(np.max(np.abs(np.linalg.norm(vectors, axis=-1) - geometry.link_length)))
    if residual > 1e-6 * geometry.link_length:
        raise InputError(f'position {t.tolist()} and heights {b.tolist()} do not close the loop '
                         f'(seed 002 eq. 3): a link is off its length by {residual:.3g} m')
    return t, b, vectors / geometry.link_length


def _check_inverse(t: FloatArray, direction_y: FloatArray) -> None:
    for j in range(2):
        if abs(float(direction_y[j])) < SINGULAR:
            raise InputError(f'position {t.tolist()}: inverse singularity, the links of slider '
                             f'{j + 1} are perpendicular to its guide (l_y = '
                             f'{float(direction_y[j]):.3g}): the slider velocity is unbounded')


def jacobian(geometry: PlanarParallel, position: ArrayLike,
             heights: ArrayLike | None = None) -> FloatArray:
    """Velocity Jacobian J (2, 2) (dimensionless) with ḃ = J·ṫ (slider velocities from the
    platform velocity, seed 002 eq. 10: ḃ_j = l_j·ṫ / l_jy) at ``position`` (2,) with
    ``heights`` (2,) (the hanging branch if None). InputError at an inverse singularity
    (l_jy = 0); J is singular at a forward one (:func:`singularity`)."""
    t, _, directions = _configuration(geometry, position, heights)
    rows = directions[[0, 2]]
    _check_inverse(t, rows[:, 1])
    out: FloatArray = rows / rows[:, 1:2]
    return out


class Singularity(NamedTuple):
    """Singularities at a configuration: ``inverse`` per slider (its links perpendicular to
    the guide, l_jy = 0: an IK double root at the workspace boundary, J unbounded), ``forward``
    (left and right links parallel, l_1 × l_3 = 0: an FK double root, J singular, the platform
    moves across the links with the sliders locked); ``direction_y`` (2,) the l_jy and
    ``determinant`` l_1 × l_3 (the machine's branch has it < 0)."""

    inverse: tuple[bool, bool]
    forward: bool
    direction_y: FloatArray
    determinant: float

    def describe(self) -> str:
        """The singularities in words, or 'regular'."""
        words = [f'inverse singularity: the links of slider {j + 1} are perpendicular to its '
                 'guide (IK double root, workspace boundary)'
                 for j in range(2) if self.inverse[j]]
        if self.forward:
            words.append('forward singularity: the left and right links are parallel (FK double '
                         'root; the platform is not held across them)')
        return '; '.join(words) or 'regular'


def singularity(geometry: PlanarParallel, position: ArrayLike,
                heights: ArrayLike | None = None, tolerance: float = SINGULAR) -> Singularity:
    """The singularities of the configuration (``heights`` default: the hanging branch)."""
    _, _, directions = _configuration(geometry, position, heights)
    rows = directions[[0, 2]]
    det = float(_cross(rows[0], rows[1]))
    return Singularity((bool(abs(rows[0, 1]) < tolerance), bool(abs(rows[1, 1]) < tolerance)),
                       abs(det) < tolerance, rows[:, 1].copy(), det)


class LinkMotion(NamedTuple):
    """The links' motion for a platform velocity and acceleration (seed 002 eqs. 7-18; base
    frame, SI): slider velocities ḃ (2,) (m/s) and accelerations b̈ (2,) (m/s²); per link the
    angular velocity ω_i (4,) (rad/s, about +z) and acceleration α_i (4,) (rad/s²) and the
    acceleration of its centre of mass (at L/2) a_Ci (4, 2) (m/s²)."""

    slider_velocity: FloatArray
    slider_acceleration: FloatArray
    angular_velocity: FloatArray
    angular_acceleration: FloatArray
    centroid_acceleration: FloatArray


def link_motion(geometry: PlanarParallel, position: ArrayLike, velocity: ArrayLike,
                acceleration: ArrayLike, heights: ArrayLike | None = None) -> LinkMotion:
    """The links' motion with the platform at ``position`` (2,) (m) moving at ``velocity`` (2,)
    (m/s) with ``acceleration`` (2,) (m/s²) (``heights`` default: the hanging branch):
    ḃ = l·v/l_y (eq. 10), ω = (l × (v − ḃ·e2))/L (eq. 11), b̈ = (l·a + L·ω²)/l_y (eq. 16),
    α = (l × (a − b̈·e2))/L (eq. 17), a_C = b̈·e2 + (L/2)·(α·e3 × l − ω²·l) (eq. 18).
    InputError at an inverse singularity."""
    t, _, directions = _configuration(geometry, position, heights)
    v = _finite(velocity, (2,), 'velocity', 'm/s')
    a = _finite(acceleration, (2,), 'acceleration', 'm/s^2')
    length = geometry.link_length
    _check_inverse(t, directions[[0, 2], 1])
    ly = directions[:, 1]
    bdot = directions @ v / ly
    omega = _cross(directions, v - bdot[:, None] * _E2) / length
    b2dot = (directions @ a + length * omega**2) / ly
    alpha = _cross(directions, a - b2dot[:, None] * _E2) / length
    centroid = (b2dot[:, None] * _E2 + 0.5 * length * (alpha[:, None] * _normal(directions)
                                                       - (omega**2)[:, None] * directions))
    return LinkMotion(bdot[[0, 2]], b2dot[[0, 2]], omega, alpha, centroid)


# -- statics with deformation compatibility (seed 002 §2-3) -------------------------------------
def error_jacobian(geometry: PlanarParallel, position: ArrayLike,
                   heights: ArrayLike | None = None) -> FloatArray:
    """J_e (4, 3) of seed 002 eq. 28: the links' elongations ΔL = J_e·(δx, δy, δφ) for a small
    platform error (m, m, rad; rotation about the platform centre), rows
    (l_x, l_y, (A_i × l_i)_z) (eq. 27)."""
    _, _, directions = _configuration(geometry, position, heights)
    a = np.asarray(geometry.platform_joints, dtype=float)
    return np.column_stack([directions, _cross(a, directions)])


def link_wrenches(geometry: PlanarParallel, position: ArrayLike,
                  heights: ArrayLike | None = None) -> FloatArray:
    """Planar unit wrenches (4, 3) (f_x, f_y, m_z about the platform centre) that a unit
    tension of each link exerts on the platform: the line through A_i along −l_i (= −J_e)."""
    out: FloatArray = -error_jacobian(geometry, position, heights)
    return out


class PlanarStatics(NamedTuple):
    """Forces and the platform error of seed 002's mechanism at one configuration (SI, base
    frame; link tensions positive).

    forces (4,): the axial force f_i at the platform joint A_i (N, tension: pulls the platform
    toward B_i), from equilibrium (eq. 24) + compatibility (eq. 28); forces_at_sliders (4,):
    the axial force at B_i, f_i + w_i·L; transverse (4,): the platform's force on link i at A_i
    along n_i = e3 × l_i (N, from the link's moment balance, eq. 21); distributed (4,): the
    links' axial load w_i = (p_i + q_i)·l_i (N/m, eq. 29); elongations (4,): ΔL_i (m, eq. 29
    integrated); deflection (3,): the platform error (δx m, δy m, δφ rad, eq. 28);
    platform_joint_forces (4, 2) and slider_joint_forces (4, 2): the force each link exerts on
    the platform and on its slider (N); drive_forces (2,): the force each drive exerts on its
    slider along +y (N), guide_forces (2,): the guides' reaction along x (N); pseudo_inverse
    (4,): the rigid minimum-norm tensions (N, blind to stiffness and misfit); heights (2,),
    directions (4, 2); and the planar problem: wrenches (4, 3), stiffness (4,) (N/m), load (3,)
    (N, N·m about the platform centre), initial (4,) (m, in the sense of W·δx) with its
    equilibrium_residual and compatibility_residual (dimensionless, ~0)."""

    position: FloatArray
    heights: FloatArray
    directions: FloatArray
    forces: FloatArray
    forces_at_sliders: FloatArray
    transverse: FloatArray
    distributed: FloatArray
    elongations: FloatArray
    deflection: FloatArray
    platform_joint_forces: FloatArray
    slider_joint_forces: FloatArray
    drive_forces: FloatArray
    guide_forces: FloatArray
    pseudo_inverse: FloatArray
    wrenches: FloatArray
    stiffness: FloatArray
    load: FloatArray
    initial: FloatArray
    equilibrium_residual: float
    compatibility_residual: float


def solve_statics(geometry: PlanarParallel, parts: PlanarParts, position: ArrayLike,
                  force: ArrayLike = (0.0, 0.0), moment: float = 0.0,
                  velocity: ArrayLike = (0.0, 0.0), acceleration: ArrayLike = (0.0, 0.0),
                  misfit: ArrayLike | None = None,
                  heights: ArrayLike | None = None) -> PlanarStatics:
    """The four link forces, the platform error and the drive forces (seed 002 §2-3).

    At the platform ``position`` (2,) (m; ``heights`` default: the hanging branch), under the
    external ``force`` (2,) (N) and ``moment`` (N·m about the platform centre) on the platform,
    the weights of every part and, given the platform's ``velocity`` (m/s) and ``acceleration``
    (m/s²), their d'Alembert inertia (eqs. 19-23; the links' through :func:`link_motion`).

    Each link (uniform bar, load G_i = m_i·(g − a_Ci)): its moment balance about B_i (eq. 21)
    fixes the transverse force at A_i, τ_i = (J_i·α_i − (L/2)·G_i·n_i)/L; its axial force is
    f_i at A_i and f_i + w_i·L at B_i, w_i = G_i·l_i/L (eq. 29), so that it lengthens by
    ΔL_i = f_i/k_i + w_i·L²/(2·E·S_i) (k_i = E·S_i/L). The platform's three balances (eq. 24)
    leave one of the four f_i free; compatibility (eq. 28), J_e·δx = ΔL + ``misfit`` (4,) (m,
    each link's free length minus L, default 0), closes them, through
    :func:`positioning_cell.mechanics.overconstrained.solve_compatible` in the plane with the
    initial deformation d0 = −(w·L²/(2·E·S) + misfit). Each slider is held along its guide by
    its drive: the vertical components of its links' forces plus its weight and inertia.
    InputError at a forward singularity (the links span rank < 3) or an unreachable position.
    """
    t, b, directions = _configuration(geometry, position, heights)
    f_ext = _finite(force, (2,), 'force', 'N')
    m_ext = float(_finite(moment, (), 'moment', 'N m'))
    v = _finite(velocity, (2,), 'velocity', 'm/s')
    a = _finite(acceleration, (2,), 'acceleration', 'm/s^2')
    length = geometry.link_length
    misfit_arr = np.zeros(4) if misfit is None else _finite(misfit, (4,), 'misfit', 'm')
    g = np.asarray(parts.gravity, dtype=float)
    masses = np.asarray(parts.link_masses, dtype=float)
    rigidity = parts.youngs_modulus * np.asarray(parts.link_sections, dtype=float)
    if np.any(v) or np.any(a):
        motion = link_motion(geometry, t, v, a, b)
        alpha, a_centroid, b2dot = (motion.angular_acceleration, motion.centroid_acceleration,
                                    motion.slider_acceleration)
    else:
        alpha, a_centroid, b2dot = np.zeros(4), np.zeros((4, 2)), np.zeros(2)
    normals = _normal(directions)
    loads = masses[:, None] * (g - a_centroid)                       # G_i, eq. 19
    inertia = masses * length**2 / 12.0
    transverse = (inertia * alpha - 0.5 * length * np.sum(loads * normals, axis=1)) / length
    distributed = np.sum(loads * directions, axis=1) / length       # w_i, eq. 29
    joints = np.asarray(geometry.platform_joints, dtype=float)
    across = transverse[:, None] * normals
    platform_load = parts.platform_mass * (g - a)
    load = np.concatenate([
        f_ext + platform_load - across.sum(axis=0),
        [m_ext + float(_cross(np.asarray(parts.platform_centre_of_mass), platform_load))
         - float(_cross(joints, across).sum())]])
    wrenches = link_wrenches(geometry, t, b)
    stiffness = parts.axial_stiffness(geometry)
    free = oc.axial_loading(0.0, distributed, length, rigidity).elongation
    initial = -(free + misfit_arr)
    solution = oc.solve_compatible(wrenches, stiffness, load, initial, space='planar')
    forces = solution.forces
    if solution.deflection is None:  # pragma: no cover - solve_compatible always returns one
        raise ConvergenceError('the compatible solution has no platform error')
    bars = oc.axial_loading(forces, distributed, length, rigidity)
    on_links = forces[:, None] * directions + across                  # platform → link at A_i
    on_sliders = on_links + loads                                      # link → slider at B_i
    sliders = np.asarray(parts.slider_masses, dtype=float)[:, None] * (g - b2dot[:, None] * _E2)
    held = np.stack([on_sliders[:2].sum(axis=0), on_sliders[2:].sum(axis=0)]) + sliders
    return PlanarStatics(
        t, b, directions, forces, bars.force_at_start, transverse, distributed, bars.elongation,
        solution.deflection, -on_links, on_sliders, -held[:, 1], -held[:, 0],
        oc.solve_pseudo_inverse(wrenches, load, space='planar').forces, wrenches, stiffness,
        load, initial, oc.equilibrium_residual(wrenches, forces, load, space='planar'),
        oc.compatibility_residual(wrenches, stiffness, forces, initial, space='planar'))
