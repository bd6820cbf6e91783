"""Statics and compliance of the 3-UPS positioner (seed 002): payload, actuator loads by the
Jacobian transpose, the forces each joint carries, and the platform's deflection under load.

Wrenches on the platform are (force N, moment N·m about the platform origin), base-frame axes,
the dual of the twist (v, ω) of :func:`positioning_cell.core.kinematics.jacobian`; platform
deflections are (δp m, δθ rad rotation vector), base frame. Actuator efforts are in the joint
order leg1_length..leg3_length, leg1_theta..leg3_theta: leg forces in N, positive when the
drive pushes the platform away (leg in compression); θ torques in N·m, positive toward +θ.

Machine parts (seed 002 §2): the platform and the payload are rigid bodies fixed to the
platform frame; each leg is a cylinder (fixed to the U yoke, centre of mass at a fixed distance
from A_i) and a rod (fixed to the ball end, centre of mass at a fixed distance from B_i), both
slender (no inertia about the leg axis). Their weight and inertia enter the actuator loads by
virtual power through the velocity of their centres of mass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import inverse as inverse_kinematics
from positioning_cell.core.kinematics import jacobian, leg_directions
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, as_vectors, matrix_from_quaternion
from positioning_cell.core.vectors import cross
from positioning_cell.mechanics.screw import theta_rate_direction
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]
Triple = tuple[float, float, float]
Matrix3 = tuple[Triple, Triple, Triple]

#: Standard gravity, m/s².
STANDARD_GRAVITY = 9.80665

#: Default gravity in the base frame for a base mounted vertically (seed 000: a panel
#: positioner stands beside the fuselage with its mechanism axis, base z, horizontal). Base −y
#: is down: leg 1 (azimuth 90°) is on top, legs 2 and 3 share the bottom symmetrically about
#: the vertical plane x = 0, and the mechanism axis z stays horizontal.
VERTICAL_BASE_GRAVITY: Triple = (0.0, -STANDARD_GRAVITY, 0.0)


#: Default payload inertia (kg·m², platform frame, about its centre): a 50 kg plate
#: 0.8 m (x) × 0.5 m (y), m·b²/12, m·a²/12, m·(a² + b²)/12.
PANEL_INERTIA: Matrix3 = ((1.0417, 0.0, 0.0), (0.0, 2.6667, 0.0), (0.0, 0.0, 3.7083))
#: Default platform inertia (kg·m²): a 2.5 kg aluminium disc Ø160 mm × 20 mm.
PLATFORM_INERTIA: Matrix3 = ((4.1e-3, 0.0, 0.0), (0.0, 4.1e-3, 0.0), (0.0, 0.0, 8.0e-3))


def _matrix3(value: Any) -> Any:
    """3 principal moments (a diagonal inertia) or 9 numbers, as 9 numbers row-major."""
    arr = np.asarray(value, dtype=float).ravel()
    return np.diag(arr).ravel() if arr.size == 3 else arr


@dataclass(frozen=True)
class Payload:
    """What the platform carries, and gravity (the ``payload:`` block, shared by every node).

    mass (kg); centre_of_gravity (m, platform frame); inertia (kg·m², about the centre of
    gravity, platform frame); external_wrench (force N, moment N·m about the platform origin,
    base frame: a clamping or tool load); gravity (m/s², base frame; default: base mounted
    vertically, base −y down, see :data:`VERTICAL_BASE_GRAVITY`). Default: a 50 kg panel
    0.8 m × 0.5 m in the platform x-y plane, its centre 0.1 m out along the platform normal.
    """

    mass: float = setting(50.0, 'mass of the payload (the panel)', 'kg', low=0.0)
    centre_of_gravity: Triple = setting((0.0, 0.0, 0.1), 'centre of gravity, platform frame',
                                        'm')
    inertia: Matrix3 = setting(PANEL_INERTIA, 'inertia about the centre of gravity, platform '
                               'frame: 3 principal moments or 9 numbers', 'kg m^2',
                               convert=_matrix3)
    external_wrench: tuple[float, float, float, float, float, float] = setting(
        (0.0,) * 6, 'external force and moment about the platform origin, base frame',
        'N, N m')
    gravity: Triple = setting(VERTICAL_BASE_GRAVITY, 'gravity in the base frame', 'm/s^2')

    def __post_init__(self) -> None:
        check_fields(self)
        _check_inertia('inertia', self.inertia)


@dataclass(frozen=True)
class Structure:
    """Stiffness and mass of the machine's own parts (the ``structure:`` block, SI).

    leg_stiffness (N/m): axial stiffness of a leg, ballscrew drive + rod in series. Default
    5e7: screw shaft EA/L (Ø16 mm, root Ø13 mm, 0.2 m: 1.4e8), preloaded nut (~2.5e8),
    fixed-end bearing pair (~2e8) and rod tube (~3e8) in series give ≈ 5e7 N/m.
    theta_stiffness (N·m/rad): torsional stiffness of the θ drive at the U joint (gear + motor
    brake); default 4e4, the order of a size-25 strain-wave gear; ``inf`` means rigid.
    platform_*: the moving platform (kg, m in the platform frame, kg·m² about its centre of
    mass). cylinder_*: the leg's fixed part (motor, housing, screw), centre of mass at
    cylinder_offset (m) from the U centre along the leg, inertia about a transverse axis
    through it. rod_*: the sliding rod, centre of mass at rod_offset (m) from the ball centre
    back along the leg.
    """

    leg_stiffness: float = setting(5.0e7, 'axial stiffness of a leg (drive + rod in series)',
                                   'N/m', low=0.0, low_open=True, finite=False)
    theta_stiffness: float = setting(4.0e4, 'torsional stiffness of the theta drive (.inf: '
                                     'rigid)', 'N m/rad', low=0.0, low_open=True, finite=False)
    platform_mass: float = setting(2.5, 'platform with sockets', 'kg', low=0.0)
    platform_centre_of_gravity: Triple = setting((0.0, 0.0, 0.01), 'platform centre of '
                                                 'gravity, platform frame', 'm')
    platform_inertia: Matrix3 = setting(PLATFORM_INERTIA, 'platform inertia about its centre of '
                                        'gravity: 3 principal moments or 9 numbers', 'kg m^2',
                                        convert=_matrix3)
    cylinder_mass: float = setting(1.2, 'leg part fixed to the U yoke (motor, housing, screw)',
                                   'kg', low=0.0)
    cylinder_offset: float = setting(0.06, 'its centre of gravity from the U centre along the '
                                     'leg', 'm', low=0.0)
    cylinder_inertia: float = setting(3.2e-3, 'its inertia about a transverse axis through its '
                                      'centre of gravity', 'kg m^2', low=0.0)
    rod_mass: float = setting(0.3, 'sliding rod with nut and ball', 'kg', low=0.0)
    rod_offset: float = setting(0.06, 'its centre of gravity from the ball centre back along '
                                'the leg', 'm', low=0.0)
    rod_inertia: float = setting(3.6e-4, 'its transverse inertia about its centre of gravity',
                                 'kg m^2', low=0.0)

    def __post_init__(self) -> None:
        check_fields(self)
        _check_inertia('platform_inertia', self.platform_inertia)

    @property
    def leg_mass(self) -> float:
        """Cylinder + rod, kg."""
        return self.cylinder_mass + self.rod_mass


def _check_inertia(name: str, value: Matrix3) -> None:
    arr = np.asarray(value, dtype=float)
    if not np.allclose(arr, arr.T, atol=1e-12) or np.linalg.eigvalsh(arr)[0] < -1e-12:
        raise ParameterError(name, value, 'must be symmetric positive semi-definite (kg m^2)')


# -- bodies and the wrench the actuators must supply ------------------------------------------
class RigidBody(NamedTuple):
    """A body fixed to the platform: mass kg, centre (3,) m and inertia (3, 3) kg·m² about it,
    both in the platform frame."""

    mass: float
    centre: FloatArray
    inertia: FloatArray


def platform_bodies(payload: Payload, structure: Structure) -> tuple[RigidBody, RigidBody]:
    """The payload and the platform as rigid bodies fixed to the platform frame."""
    return (RigidBody(payload.mass, np.asarray(payload.centre_of_gravity),
                      np.asarray(payload.inertia)),
            RigidBody(structure.platform_mass, np.asarray(structure.platform_centre_of_gravity),
                      np.asarray(structure.platform_inertia)))


class LegState(NamedTuple):
    """Leg geometry of N poses: lengths (N, 3) m, unit leg vectors u (N, 3, 3), the θ-rate
    direction w = ∂u/∂θ (N, 3, 3), r_i = R b_i (N, 3, 3) m, base frame."""

    lengths: FloatArray
    u: FloatArray
    w: FloatArray
    r: FloatArray
    thetas: FloatArray


def leg_state(mech: Mechanism, p: FloatArray, q: FloatArray) -> LegState:
    """Leg geometry at validated poses (N, 3), (N, 4)."""
    joints = inverse_kinematics(mech, p, q)
    u = leg_directions(mech, joints.phis, joints.thetas)
    w = theta_rate_direction(mech.tangential, u)
    r = np.einsum('nij,kj->nki', matrix_from_quaternion(q), mech.platform_joints)
    return LegState(joints.lengths, u, w, r, joints.thetas)


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    out: FloatArray = np.sum(a * b, axis=-1, keepdims=True)
    return out


def required_wrench(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                    payload: Payload, structure: Structure | None = None,
                    twist: ArrayLike | None = None,
                    twist_rate: ArrayLike | None = None) -> FloatArray:
    """The wrench (N, 6) the actuators must exert on the platform (force N, moment N·m about the
    platform origin, base frame) to hold it against gravity and ``payload.external_wrench`` and,
    given the platform twist (N, 6) (v m/s, ω rad/s) and its rate (N, 6) (m/s², rad/s²), to
    accelerate the platform, the payload and the legs (d'Alembert, seed 002 eqs. 19-23).

    A leg part whose centre of mass moves with velocity V·Ḃ_i enters as the equivalent force
    Vᵀ·m(a − g) at B_i (virtual power); the slender leg's rotation as (J u × ü) × u / l.
    Actuator efforts are τ = Jᵀ·(this wrench) (:func:`actuator_efforts`).
    """
    s = structure or Structure()
    p, q = as_pose_batch(position, quaternion)
    n = p.shape[0]
    moving = twist is not None or twist_rate is not None
    t = as_vectors(twist if twist is not None else np.zeros((n, 6)), 6, 'twist')
    tr = as_vectors(twist_rate if twist_rate is not None else np.zeros((n, 6)), 6, 'twist_rate')
    g = np.asarray(payload.gravity)
    rot = matrix_from_quaternion(q)
    v, omega, a, alpha = t[:, :3], t[:, 3:], tr[:, :3], tr[:, 3:]
    force = np.zeros((n, 3))
    moment = np.zeros((n, 3))
    for body in platform_bodies(payload, s):
        rc = rot @ body.centre
        acc = a + cross(alpha, rc) + cross(omega, cross(omega, rc)) if moving else 0.0
        f = body.mass * (acc - g)
        force += f
        moment += cross(rc, f)
        if moving:
            inertia = rot @ body.inertia @ rot.transpose(0, 2, 1)
            moment += (np.einsum('nij,nj->ni', inertia, alpha)
                       + cross(omega, np.einsum('nij,nj->ni', inertia, omega)))
    legs = leg_state(mech, p, q)
    f_leg = leg_equivalent_forces(legs, s, g, v, omega, a, alpha) if moving else \
        leg_equivalent_forces(legs, s, g)
    force += f_leg.sum(axis=1)
    moment += cross(legs.r, f_leg).sum(axis=1)
    wrench: FloatArray = np.hstack([force, moment]) - np.asarray(payload.external_wrench)
    return wrench


def leg_equivalent_forces(legs: LegState, structure: Structure, gravity: FloatArray,
                          v: FloatArray | None = None, omega: FloatArray | None = None,
                          a: FloatArray | None = None,
                          alpha: FloatArray | None = None) -> FloatArray:
    """Equivalent forces (N, 3, 3) at B_i of the legs' weight and inertia (virtual power):
    cylinder centre c = A + s_c u moves as (s_c/l)(I − uuᵀ)Ḃ, rod centre c = B − s_r u as
    (I − (s_r/l)(I − uuᵀ))Ḃ, leg rotation ω = u × Ḃ / l. Static when no motion is given."""
    s = structure
    length, u = legs.lengths[..., None], legs.u
    if v is None or omega is None or a is None or alpha is None:
        c_acc = r_acc = np.zeros_like(u)
        spin = np.zeros_like(u)
    else:
        b_dot = v[:, None, :] + cross(omega[:, None, :], legs.r)
        b_ddot = (a[:, None, :] + cross(alpha[:, None, :], legs.r)
                  + cross(omega[:, None, :], cross(omega[:, None, :], legs.r)))
        l_dot = _dot(u, b_dot)
        u_dot = (b_dot - l_dot * u) / length
        l_ddot = _dot(u_dot, b_dot) + _dot(u, b_ddot)
        u_ddot = (b_ddot - l_ddot * u - 2.0 * l_dot * u_dot) / length
        c_acc = s.cylinder_offset * u_ddot
        r_acc = b_ddot - s.rod_offset * u_ddot
        spin = (s.cylinder_inertia + s.rod_inertia) * cross(u, u_ddot)
    f_cyl = s.cylinder_mass * (c_acc - gravity)
    f_rod = s.rod_mass * (r_acc - gravity)
    f_cyl_perp = f_cyl - _dot(u, f_cyl) * u
    f_rod_perp = f_rod - _dot(u, f_rod) * u
    out: FloatArray = (s.cylinder_offset / length * f_cyl_perp + f_rod
                       - s.rod_offset / length * f_rod_perp + cross(spin, u) / length)
    return out


def efforts_from_wrench(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                        wrench: FloatArray) -> FloatArray:
    """τ = Jᵀ·wrench (N, 6): actuator efforts (N, N·m) that exert ``wrench`` (N, 6) on the
    platform (virtual work: τ·q̇ = wrench·twist)."""
    jac = jacobian(mech, position, quaternion).matrix
    out: FloatArray = np.einsum('nji,nj->ni', jac, wrench)
    return out


def wrench_from_efforts(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                        efforts: ArrayLike) -> FloatArray:
    """The wrench (N, 6) (N; N·m about the platform origin, base frame) that actuator efforts
    (N, 6) (N, N·m) exert on the platform at poses (N, 3) m, (N, 4): τ = Jᵀ·w solved for w,
    the inverse of :func:`efforts_from_wrench` away from singularities (seed 002 §2: what
    the legs' load cells say the platform carries)."""
    jac = jacobian(mech, position, quaternion).matrix
    tau = np.asarray(efforts, dtype=float).reshape(jac.shape[0], 6)
    out: FloatArray = np.linalg.solve(np.swapaxes(jac, 1, 2), tau[..., None])[..., 0]
    return out


def actuator_efforts(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                     payload: Payload, structure: Structure | None = None) -> FloatArray:
    """Static actuator efforts (N, 6) holding ``payload`` at poses (N, 3) m, (N, 4) x, y, z, w:
    leg forces (N, + = drive pushes, leg in compression) then θ torques (N·m), joint order
    leg1_length..leg3_length, leg1_theta..leg3_theta. Includes the platform's and the legs'
    own weight (``structure``, default :class:`Structure`). τ = Jᵀ·w (seed 002 §2)."""
    return efforts_from_wrench(mech, position, quaternion,
                               required_wrench(mech, position, quaternion, payload, structure))


class JointForces(NamedTuple):
    """Forces (N, 3 legs, 3) in N, base frame: ``at_platform`` = force leg i exerts on the
    platform at the ball centre B_i; ``at_base`` = force leg i exerts on the base at the U
    centre A_i."""

    at_platform: FloatArray
    at_base: FloatArray


def joint_forces(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                 payload: Payload, structure: Structure | None = None,
                 efforts: FloatArray | None = None) -> JointForces:
    """Static forces in the S and U joints from the actuator efforts and each leg's equilibrium
    (Newton-Euler, seed 002 eqs. 19-21). With G = Σ (c − A) × m g the legs' weight moment about
    A_i and (u, w = ∂u/∂θ, v = e_t × u / cos θ) orthonormal, the force on the platform is
    F_B = (F_l + m_rod g·u) u + (τ_θ + (u × w)·G)/l w + (e_t·G)/(l cos θ) v
    (axial: the rod's balance; w: the θ drive; v: the passive φ axis carries no moment), and the
    force on the base F_A = m_leg g − F_B. ``efforts``: the :func:`actuator_efforts` (N, 6) at
    these poses when the caller has them already (None: computed here)."""
    s = structure or Structure()
    p, q = as_pose_batch(position, quaternion)
    tau = actuator_efforts(mech, p, q, payload, s) if efforts is None else efforts
    legs = leg_state(mech, p, q)
    g = np.asarray(payload.gravity)
    length, u, w = legs.lengths[..., None], legs.u, legs.w
    lever = s.cylinder_mass * s.cylinder_offset + s.rod_mass * (length - s.rod_offset)
    moment = lever * cross(u, np.broadcast_to(g, u.shape))
    et = np.broadcast_to(mech.tangential, u.shape)
    v_dir = cross(et, u)
    axial = tau[:, :3, None] + s.rod_mass * _dot(u, np.broadcast_to(g, u.shape))
    lateral = (tau[:, 3:, None] + _dot(cross(u, w), moment)) / length
    passive = _dot(et, moment) / (length * _dot(v_dir, v_dir))
    at_platform = axial * u + lateral * w + passive * v_dir
    return JointForces(at_platform, s.leg_mass * g - at_platform)


# -- compliance and deflection (seed 002 §3) ----------------------------------------------------
def joint_compliance(structure: Structure) -> FloatArray:
    """Diagonal compliance (6,) of the drives: 1/k_l (m/N) ×3, 1/k_θ (rad/(N·m)) ×3."""
    return np.array([1.0 / structure.leg_stiffness] * 3 + [1.0 / structure.theta_stiffness] * 3)


def compliance(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
               structure: Structure | None = None) -> FloatArray:
    """Platform compliance C = J·K⁻¹·Jᵀ (N, 6, 6): deflection (δp m, δθ rad) per load wrench
    (N, N·m about the platform origin) on the platform, drives elastic, links rigid."""
    jac = jacobian(mech, position, quaternion).matrix
    c = joint_compliance(structure or Structure())
    out: FloatArray = np.einsum('nik,k,njk->nij', jac, c, jac)
    return out


class Deflection(NamedTuple):
    """Platform deflection under load: translation (N, 3) m and rotation vector (N, 3) rad,
    base frame; joint_deformation (N, 6) (m, rad): δq = −K⁻¹τ, the drives yielding to their
    efforts (a pushing leg shortens); efforts (N, 6) the static actuator efforts."""

    translation: FloatArray
    rotation: FloatArray
    joint_deformation: FloatArray
    efforts: FloatArray


def deflection(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike, payload: Payload,
               structure: Structure | None = None) -> Deflection:
    """Small-deflection pose error δx = J·δq = −C·w of the platform under ``payload`` (w the
    wrench the actuators supply), seed 002 eq. 28 (leg deformation ↔ platform pose error)."""
    s = structure or Structure()
    w = required_wrench(mech, position, quaternion, payload, s)
    dx = -np.einsum('nij,nj->ni', compliance(mech, position, quaternion, s), w)
    tau = efforts_from_wrench(mech, position, quaternion, w)
    return Deflection(dx[:, :3], dx[:, 3:], -tau * joint_compliance(s), tau)

