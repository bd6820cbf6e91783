"""A real machine as the cell models it: the nominal mechanism with geometric errors of its
joint centres, zero offsets of its encoders and joint clearance. The simulator's truth is one
such machine; a calibration identifies another from measurements.

Joints: the drives report the encoder values l_enc, θ_enc; the machine's real leg length and
second U angle are l = l_enc + δl and θ = θ_enc + δθ (``length_offsets`` δl in m,
``theta_offsets`` δθ in rad, per leg). The joint centres are the mechanism's own
(``Mechanism.base_offsets`` / ``platform_offsets``), the clearance any model of
:mod:`positioning_cell.clearance` over that mechanism.

Terms beyond geometry (:class:`MachineTerms`, all zero by default: the model is then the
rigid, isothermal one), in joint space. With l, θ the joint values the pose needs on the
machine expanded by ε = α_s ΔT (ΔT = temperature − ``reference_temperature``; the seated
joint centres, base and platform frames, scaled by 1 + ε: the cold machine scaled, so at
(p, R) its legs are (1 + ε) times the cold machine's at (p / (1 + ε), R), θ the same), the
encoders read

    e_l = l (1 − α_l ΔT − s_i) + s_i l_mid + c_l,i F_i + h_l,i a_i − δl_i
    e_θ = θ + c_θ,i τ_i + h_θ,i a_{3+i} − δθ_i

α_l the legs' expansion coefficient (1/K), s_i leg i's lead scale (the screw's lead error,
relative to the mid length l_mid = (length_min + length_max)/2), c the axial (m/N) and θ
torsional (rad/(N m)) compliances times the joint efforts F, τ of the statics at the pose with
the model's payload (seed 002 eq. 28: δq = −C τ; a leg in compression is shorter than its
encoder says), h the reversal half-band of each axis (m, rad) times its approach sign a (the
axis lags behind its encoder in the direction it moved). The compliance is the full value, not
a correction on top of ``structure.leg_stiffness``: the cell's nominal model is rigid (the
nominal stiffness only sets the expected size, :func:`~positioning_cell.calibration.parameters
.scales`). Conditions (temperature, approach) come with each call
(:class:`~positioning_cell.calibration.conditions.Conditions`; not known: ΔT = 0, a = 0).

A :class:`MachineModel` is also a :class:`positioning_cell.clearance.ClearanceLike`: the mover
uses it in place of a clearance model (it ignores the nominal mechanism it is handed and uses
its own geometry), so every mode works on the calibrated machine unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.conditions import STANDARD_TEMPERATURE, Conditions
from positioning_cell.clearance import ClearanceModel, attained_pose, compensate
from positioning_cell.core.kinematics import ForwardResult, InverseResult
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, as_vectors
from positioning_cell.mechanics.statics import Payload, Structure, actuator_efforts

FloatArray = NDArray[np.float64]

#: Most passes of the forward model's fixed point (efforts and expansion depend on the pose).
_FORWARD_PASSES = 8
#: The fixed point stops when no joint value moves more than this (m, rad).
_FORWARD_TOLERANCE = 1e-13


def _zeros() -> FloatArray:
    return np.zeros(3)


def _vector(value: ArrayLike, size: int, name: str) -> FloatArray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise ValueError(f'{name} must hold {size} finite numbers')
    return arr.copy()


@dataclass(frozen=True)
class MachineTerms:
    """The terms beyond geometry (module docstring): ``leg_compliance`` (3,) m/N,
    ``theta_compliance`` (3,) rad/(N m), ``leg_expansion`` and ``structure_expansion`` 1/K
    about ``reference_temperature`` °C, ``lead_scale`` (3,) (dimensionless), ``reversal`` (6,)
    half-bands (3 legs m, 3 θ rad)."""

    leg_compliance: FloatArray = field(default_factory=_zeros)
    theta_compliance: FloatArray = field(default_factory=_zeros)
    leg_expansion: float = 0.0
    structure_expansion: float = 0.0
    reference_temperature: float = STANDARD_TEMPERATURE
    lead_scale: FloatArray = field(default_factory=_zeros)
    reversal: FloatArray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        for name in ('leg_compliance', 'theta_compliance', 'lead_scale'):
            object.__setattr__(self, name, _vector(getattr(self, name), 3, name))
        object.__setattr__(self, 'reversal', _vector(self.reversal, 6, 'reversal'))
        for name in ('leg_expansion', 'structure_expansion', 'reference_temperature'):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f'{name} must be a finite number')
            object.__setattr__(self, name, value)

    @property
    def is_zero(self) -> bool:
        """No term: the rigid, isothermal, backlash-free model."""
        return not (self.leg_compliance.any() or self.theta_compliance.any()
                    or self.leg_expansion or self.structure_expansion
                    or self.lead_scale.any() or self.reversal.any())


def mid_length(mech: Mechanism) -> float:
    """l_mid (m): the middle of the legs' stroke, the origin of the lead scale."""
    return 0.5 * (mech.length_min + mech.length_max)


class LegVectors(NamedTuple):
    """Per pose and leg (N, 3): the length l m, unit leg vector u (N, 3, 3), u·e_t = sin θ,
    and w = ∂θ/∂d (N, 3, 3) 1/m (the θ row of the inverse Jacobian)."""

    length: FloatArray
    u: FloatArray
    ut: FloatArray
    w: FloatArray


def leg_vectors(d: FloatArray, tangential: FloatArray) -> LegVectors:
    """:class:`LegVectors` of the leg vectors d (N, 3, 3) m (from A_i to B_i, base frame) and
    the legs' tangential axes e_t (3, 3): l = |d|, u = d / l, θ = asin(u·e_t),
    w = (e_t − (u·e_t) u) / (l cos θ)."""
    length = np.linalg.norm(d, axis=2)
    u = d / length[..., None]
    ut = np.einsum('nkj,kj->nk', u, tangential)
    cos_t = np.sqrt(np.clip(1.0 - ut**2, 1e-300, None))
    w = (tangential - ut[..., None] * u) / (length * cos_t)[..., None]
    return LegVectors(length, u, ut, w)


def terms_offsets(terms: MachineTerms, lengths: FloatArray, efforts: FloatArray | None,
                  change: FloatArray, approach: FloatArray, mid: float) -> tuple[FloatArray,
                                                                                 FloatArray]:
    """Encoder minus real joint value, as gain (N, 3) on the leg lengths and offset (N, 6) of
    every joint: e = l · gain + offset (legs), e = θ + offset (θ), before the zero offsets
    (module docstring). ``lengths`` (N, 3) m are only used for their count, ``efforts``
    (N, 6) N, N m (None: compliance not applied), ``change`` (N,) K, ``approach`` (N, 6)."""
    n = lengths.shape[0]
    gain = 1.0 - terms.leg_expansion * change[:, None] - terms.lead_scale
    offset = np.zeros((n, 6))
    offset[:, :3] = terms.lead_scale * mid
    if efforts is not None:
        offset += np.concatenate([terms.leg_compliance, terms.theta_compliance]) * efforts
    offset += terms.reversal * approach
    return gain, offset


@dataclass(frozen=True)
class MachineModel:
    """``mechanism`` (with its joint-centre offsets), ``clearance`` over it (None: none), the
    encoder zero offsets ``length_offsets`` (3,) m and ``theta_offsets`` (3,) rad, the
    :class:`MachineTerms` beyond geometry and the ``payload`` and ``structure`` whose statics
    drive the compliance (None: the defaults) (module docstring)."""

    mechanism: Mechanism = field(default_factory=Mechanism.default)
    clearance: ClearanceModel = None
    length_offsets: FloatArray = field(default_factory=_zeros)
    theta_offsets: FloatArray = field(default_factory=_zeros)
    terms: MachineTerms = field(default_factory=MachineTerms)
    payload: Payload | None = None
    structure: Structure | None = None

    def __post_init__(self) -> None:
        for name in ('length_offsets', 'theta_offsets'):
            value = as_vectors(getattr(self, name), 3, name)
            if value.shape != (1, 3):
                raise ValueError(f'{name} must hold 3 numbers, one per leg')
            object.__setattr__(self, name, value[0].copy())

    def with_clearance(self, clearance: ClearanceModel) -> MachineModel:
        """The same geometry and offsets with another clearance (e.g. a new payload)."""
        return replace(self, clearance=clearance)

    # -- the two uses of a machine model ----------------------------------------------------
    def poses(self, lengths: ArrayLike, thetas: ArrayLike, phi0: ArrayLike | None = None,
              conditions: Conditions | None = None) -> ForwardResult:
        """Where this machine puts the platform when its encoders read lengths (N, 3) m and
        thetas (N, 3) rad (``phi0``: previous passive angles, branch continuity) under
        ``conditions`` (None: not known). With compliance, a fixed point: the efforts depend
        on the pose reached."""
        enc_l = as_vectors(lengths, 3, 'lengths')
        enc_t = as_vectors(thetas, 3, 'thetas')
        real_l = enc_l + self.length_offsets
        real_t = enc_t + self.theta_offsets
        if self.terms.is_zero:
            return attained_pose(self.mechanism, self.clearance, real_l, real_t, phi0)
        n = enc_l.shape[0]
        change, approach = self._conditions(conditions, n)
        grow = 1.0 + self.terms.structure_expansion * change[:, None]
        efforts: FloatArray | None = None
        joints = np.zeros((n, 6))
        pose: ForwardResult | None = None
        for _ in range(_FORWARD_PASSES):
            gain, offset = terms_offsets(self.terms, enc_l, efforts, change, approach,
                                         mid_length(self.mechanism))
            # the expanded machine is the cold one scaled by grow: its legs / grow, same θ
            new = np.concatenate([(real_l - offset[:, :3]) / (gain * grow),
                                  real_t - offset[:, 3:]], axis=1)
            if pose is not None and (n == 0 or np.abs(new - joints).max() <= _FORWARD_TOLERANCE):
                break
            joints = new
            cold = attained_pose(self.mechanism, self.clearance, joints[:, :3], joints[:, 3:],
                                 phi0)
            pose = cold._replace(position=cold.position * grow)
            if not self._compliant:
                break
            efforts = self._efforts(pose.position, pose.quaternion)
        assert pose is not None
        return pose

    def commands(self, position: ArrayLike, quaternion: ArrayLike,
                 conditions: Conditions | None = None) -> InverseResult:
        """Encoder values (lengths m, thetas rad) that put this machine on poses (N, 3) m,
        (N, 4) x, y, z, w in ``base`` under ``conditions`` (None: not known); phis are the
        passive angles the machine shows."""
        if self.terms.is_zero:
            real = compensate(self.mechanism, self.clearance, position, quaternion)
            return InverseResult(real.lengths - self.length_offsets,
                                 real.thetas - self.theta_offsets, real.phis)
        p, q = as_pose_batch(position, quaternion)
        n = p.shape[0]
        change, approach = self._conditions(conditions, n)
        grow = 1.0 + self.terms.structure_expansion * change[:, None]
        real = compensate(self.mechanism, self.clearance, p / grow, q)
        efforts = self._efforts(p, q) if self._compliant else None
        gain, offset = terms_offsets(self.terms, real.lengths, efforts, change, approach,
                                     mid_length(self.mechanism))
        lengths = real.lengths * grow * gain + offset[:, :3] - self.length_offsets
        thetas = real.thetas + offset[:, 3:] - self.theta_offsets
        return InverseResult(lengths, thetas, real.phis)

    def _conditions(self, conditions: Conditions | None, n: int) -> tuple[FloatArray,
                                                                          FloatArray]:
        c = conditions or Conditions()
        return c.temperature_change(n, self.terms.reference_temperature), c.approach_signs(n)

    @property
    def _compliant(self) -> bool:
        return bool(self.terms.leg_compliance.any() or self.terms.theta_compliance.any())

    def _efforts(self, position: FloatArray, quaternion: FloatArray) -> FloatArray:
        """The joint efforts (N, 6) at poses, N and N m (the statics of this machine's
        payload and structure)."""
        return actuator_efforts(self.mechanism, position, quaternion,
                                self.payload or Payload(), self.structure or Structure())

    def at(self, conditions: Conditions) -> MachineModel | ConditionedMachine:
        """This machine under fixed ``conditions`` as a compensation model (ClearanceLike):
        itself when its terms do not depend on them."""
        return self if self.terms.is_zero else ConditionedMachine(self, conditions)

    # -- ClearanceLike (the mover's compensation model) -------------------------------------
    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """:meth:`poses` (``mech``, the nominal machine, is not used)."""
        return self.poses(lengths, thetas, phi0)

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """:meth:`commands` (``mech``, the nominal machine, is not used)."""
        return self.commands(position, quaternion)


@dataclass(frozen=True)
class ConditionedMachine:
    """A :class:`MachineModel` under fixed ``conditions`` (one temperature, one approach row
    for every pose): the ClearanceLike the mover compensates with while those hold."""

    machine: MachineModel
    conditions: Conditions

    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """:meth:`MachineModel.poses` under the conditions (``mech`` not used)."""
        return self.machine.poses(lengths, thetas, phi0, self.conditions)

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """:meth:`MachineModel.commands` under the conditions (``mech`` not used)."""
        return self.machine.commands(position, quaternion, self.conditions)
