"""The simulated machine as it really is: the nominal mechanism with geometric errors of its
joint centres, zero offsets of its encoders and its joint clearance (what the cell's
calibration identifies), and the effects outside that model (:mod:`positioning_cell.sim.effects`):
drive errors, temperature and compliance. Only the simulators read it; the cell judges itself
against it in reports and tests, never works from it.

With effects, the machine whose encoders read (l, θ) stands where its real joints put it:
the motors at (l + δl, θ + δθ), the drives' errors give the real axes, the legs expand with
their temperature; the pose x then satisfies IK(x) + shift(x) = real joints, the shift being
what the clearance, the expanded joint circles and the compliance at x add to the joints the
rigid machine needs, solved as a fixed point x ← FK(real − shift(x)) (each pass one batched
FK; the shift is a small, slowly varying function of x)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.conditions import Conditions as ModelConditions
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.clearance import ClearanceParameters, build, compensate
from positioning_cell.clearance.load import LoadAwareClearance, inverse_with_offsets
from positioning_cell.config import flatten
from positioning_cell.core.kinematics import ForwardResult, forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple, as_vectors
from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.parameters import (
    ParameterError,
    block,
    check_fields,
    group,
    parse,
    setting,
)
from positioning_cell.sim.effects.compliance import ComplianceParameters, yielding
from positioning_cell.sim.effects.drive_errors import DriveErrorParameters, DriveErrors
from positioning_cell.sim.effects.history import Conditions, MachineHistory
from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE, Thermal, ThermalParameters

FloatArray = NDArray[np.float64]

_ZERO = ((0.0, 0.0, 0.0),) * 3
#: Fixed point of the effects: the largest error of the joint shift (m, rad) it stops at, as
#: the contraction's rate estimates it (:func:`settled`). 1e-12 sat on the shift's own rounding
#: (the solvers inside joint_shift). A 5 mm move sampled at the simulator's 50 Hz takes 2.0
#: rounds a pose, its poses within 3e-13 m of a 1e-14 tolerance's (ad hoc; the tracker
#: simulator's CPU while the cell moves is mostly these rounds).
_TOLERANCE = 1e-11
_MAX_ITERATIONS = 30


@dataclass(frozen=True)
class TruthParameters:
    """The simulator's ``truth:`` block (read-only): the clearance (directions not given drawn
    from ``clearance.seed``) and the geometric errors: the U and S joint-centre offsets (added
    to the nominal mechanism's own, 3 legs × (x, y, z) m) and the encoders' zero offsets. Each
    error is the given value plus, when ``geometry_seed`` >= 0, a normal draw of its ``*_sigma``
    (one seeded machine per seed). The effects outside the identified model (``drives``,
    ``thermal``, ``compliance``) each have an ``enabled`` switch (:meth:`without_effects`:
    all off, the exactly-modelled machine)."""

    clearance: ClearanceParameters = group(
        ClearanceParameters, 'the machine\'s joint clearance',
        default=lambda: ClearanceParameters(seed=0))
    base_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the U centres, 3 legs x (x, y, z), base frame', 'm',
        length=9)
    platform_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the S centres, 3 legs x (x, y, z), platform frame', 'm',
        length=9)
    length_offsets: Triple = setting(
        (0.0, 0.0, 0.0), 'encoder zero offsets of the legs: real length = reading + offset',
        'm')
    theta_offsets: Triple = setting(
        (0.0, 0.0, 0.0), 'encoder zero offsets of the theta axes: real = reading + offset',
        'rad')
    geometry_seed: int = setting(-1, 'seed of the drawn geometric errors (-1: none drawn)',
                                 low=-1, high=2**31 - 1)
    joint_centre_sigma: float = setting(1e-4, 'sigma of a drawn joint-centre coordinate', 'm',
                                        low=0.0, high=0.01)
    length_offset_sigma: float = setting(1e-4, 'sigma of a drawn leg zero offset', 'm',
                                         low=0.0, high=0.01)
    theta_offset_sigma: float = setting(3e-4, 'sigma of a drawn theta zero offset', 'rad',
                                        low=0.0, high=0.1)

    drives: DriveErrorParameters = group(DriveErrorParameters, 'errors of the drives (lead, '
                                         'periodic, reversal)')
    thermal: ThermalParameters = group(ThermalParameters, 'temperature: air, legs, expansion, '
                                       'sensor, refraction')
    compliance: ComplianceParameters = group(ComplianceParameters, 'the machine\'s own '
                                             'stiffnesses under load')

    def __post_init__(self) -> None:
        check_fields(self)

    def without_effects(self) -> TruthParameters:
        """The same machine with every effect outside the identified model switched off."""
        return replace(self, drives=replace(self.drives, enabled=False),
                       thermal=replace(self.thermal, enabled=False),
                       compliance=replace(self.compliance, enabled=False))

    def geometric_errors(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(base offsets (3, 3) m, platform offsets (3, 3) m, length offsets (3,) m, theta
        offsets (3,) rad): the given values plus the seeded draws."""
        base = np.asarray(self.base_offsets, dtype=float)
        platform = np.asarray(self.platform_offsets, dtype=float)
        lengths = np.asarray(self.length_offsets, dtype=float)
        thetas = np.asarray(self.theta_offsets, dtype=float)
        if self.geometry_seed >= 0:
            rng = np.random.default_rng(self.geometry_seed)
            base = base + rng.normal(0.0, self.joint_centre_sigma, (3, 3))
            platform = platform + rng.normal(0.0, self.joint_centre_sigma, (3, 3))
            lengths = lengths + rng.normal(0.0, self.length_offset_sigma, 3)
            thetas = thetas + rng.normal(0.0, self.theta_offset_sigma, 3)
        return base, platform, lengths, thetas


@dataclass(frozen=True)
class Effects:
    """The effects of one machine outside the identified model (None: off): its ``drives``,
    ``thermal`` behaviour and ``compliance`` (with the ``payload`` and ``structure`` whose
    statics load it)."""

    drives: DriveErrors | None = None
    thermal: Thermal | None = None
    compliance: ComplianceParameters | None = None
    payload: Payload = field(default_factory=Payload)
    structure: Structure = field(default_factory=Structure)

    @property
    def active(self) -> bool:
        """Whether any effect is on."""
        return any(e is not None for e in (self.drives, self.thermal, self.compliance))

    @classmethod
    def from_parameters(cls, params: TruthParameters, mech: Mechanism,
                        payload: Payload | None = None,
                        structure: Structure | None = None) -> Effects:
        """The effects ``params`` switch on, drawn for the machine ``mech``."""
        return cls(params.drives.draw(mech.home_length) if params.drives.enabled else None,
                   params.thermal.draw() if params.thermal.enabled else None,
                   params.compliance if params.compliance.enabled else None,
                   payload or Payload(), structure or Structure())


@dataclass(frozen=True)
class Truth(MachineModel):
    """The simulated machine (a :class:`~positioning_cell.calibration.machine.MachineModel`):
    ``mechanism`` with its joint-centre geometric errors, its ``clearance`` (None: none), its
    encoders' zero offsets, and its ``effects`` outside that model (module docstring).
    :meth:`commands` stays the identified model's inverse (the effects are not inverted:
    nothing but judging uses the truth, and it judges with :meth:`poses`)."""

    effects: Effects = field(default_factory=Effects)

    def poses(self, lengths: ArrayLike, thetas: ArrayLike, phi0: ArrayLike | None = None,
              conditions: Conditions | ModelConditions | None = None) -> ForwardResult:
        """Where the machine puts the platform when its encoders read lengths (N, 3) m and
        thetas (N, 3) rad under ``conditions``: the true ones, or the cell's view of them
        (the air temperature taken for the legs' too; None: 20 °C, approach unknown); without
        effects exactly :meth:`MachineModel.poses`. ConvergenceError when the fixed point does
        not settle."""
        return self.settle(lengths, thetas, phi0, conditions)[0]

    def settle(self, lengths: ArrayLike, thetas: ArrayLike, phi0: ArrayLike | None = None,
               conditions: Conditions | ModelConditions | None = None,
               shift0: ArrayLike | None = None) -> tuple[ForwardResult, FloatArray]:
        """:meth:`poses`, and the joint shift (N, 6) m, rad its effects settled on
        (:meth:`joint_shift`; zeros without effects). ``shift0`` (N, 6) or (6,): where the
        fixed point starts (None: zero), the shift of a nearby pose for a stream of poses (the
        simulator's, each a period from the last): the same pose within the fixed point's
        tolerance, in two or three rounds instead of five."""
        if not self.effects.active:
            result = super().poses(lengths, thetas, phi0)
            return result, np.zeros((len(result.position), 6))
        real_l = as_vectors(lengths, 3, 'lengths') + self.length_offsets
        real_t = as_vectors(thetas, 3, 'thetas') + self.theta_offsets
        cond = _true_conditions(conditions, len(real_l))
        fx = self.effects
        if fx.drives is not None:
            real_l, real_t = fx.drives.actual(real_l, real_t, cond.approach)
        if fx.thermal is not None:
            real_l = fx.thermal.expanded_lengths(real_l, cond.legs)
        start = np.zeros((len(real_l), 6)) if shift0 is None else np.broadcast_to(
            np.asarray(shift0, dtype=float), (len(real_l), 6))
        if not np.all(np.isfinite(start)):
            raise InputError('shift0: the starting joint shift must be finite')
        return self._fixed_point(real_l, real_t, cond, phi0, start)

    def history(self) -> MachineHistory:
        """A history of this machine's true joint stream (its legs' heating, its axes' place
        in their reversal bands), for :meth:`poses`' conditions."""
        drives = self.effects.drives
        return MachineHistory(self.effects.thermal, None if drives is None else drives.bands)

    def _fixed_point(self, real_l: FloatArray, real_t: FloatArray, cond: Conditions,
                     phi0: ArrayLike | None, start: FloatArray
                     ) -> tuple[ForwardResult, FloatArray]:
        mech = self.mechanism
        shift = start.copy()
        result = forward(mech, real_l - shift[:, :3], real_t - shift[:, 3:], phi0)
        ok = result.converged.copy()
        previous = math.inf  # the change of the round before (none yet)
        for _ in range(_MAX_ITERATIONS):
            rows = np.flatnonzero(ok)
            new = self.joint_shift(result.position[rows], result.quaternion[rows],
                                   cond.air[rows])
            change = float(np.max(np.abs(new - shift[rows]), initial=0.0))
            shift[rows] = new
            phis = np.where(np.isfinite(result.phis), result.phis, 0.0)
            result = forward(mech, real_l - shift[:, :3], real_t - shift[:, 3:], phis)
            ok &= result.converged
            done, previous = settled(change, previous, _TOLERANCE), change
            if done:
                return ForwardResult(np.where(ok[:, None], result.position, np.nan),
                                     np.where(ok[:, None], result.quaternion, np.nan),
                                     result.phis, ok), shift
        raise ConvergenceError('the simulated machine\'s effects did not settle on a pose')

    def joint_shift(self, position: FloatArray, quaternion: FloatArray,
                    air: FloatArray) -> FloatArray:
        """What the clearance, the joint circles expanded at air temperatures (N,) °C and the
        compliance add (N, 6) m, rad to the real joints the rigid machine needs for poses
        (N, 3), (N, 4) (module docstring; first order: the effects are µm against metres)."""
        mech, fx, model = self.mechanism, self.effects, self.clearance
        rigid = inverse(mech, position, quaternion)
        yielded = None if fx.compliance is None else yielding(
            fx.compliance, mech, position, quaternion, fx.payload, fx.structure)
        if yielded is not None and isinstance(model, LoadAwareClearance) \
                and model.payload == fx.payload and model.structure == fx.structure:
            # the same statics close the clearance: computed once a pose
            held = model.compensate(mech, position, quaternion, yielded.forces)
        else:
            held = compensate(mech, model, position, quaternion)
        shift: FloatArray = np.c_[held.lengths - rigid.lengths, held.thetas - rigid.thetas]
        n = len(position)
        u_off, s_off = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
        if fx.thermal is not None:
            du, ds = fx.thermal.joint_offsets(mech.base_joints, mech.platform_joints, air)
            u_off, s_off = u_off + du, s_off + ds
        if yielded is not None:
            shift += yielded.joints
            u_off, s_off = u_off + yielded.u_offsets, s_off + yielded.s_offsets
        if fx.thermal is not None or fx.compliance is not None:
            moved = inverse_with_offsets(mech, position, quaternion, u_off, s_off)
            shift += np.c_[moved.lengths - rigid.lengths, moved.thetas - rigid.thetas]
        return shift

    @classmethod
    def from_parameters(cls, params: TruthParameters, mech: Mechanism,
                        payload: Payload | None = None,
                        structure: Structure | None = None) -> Truth:
        """The truth ``params`` describe over the nominal machine ``mech`` (ConfigError naming
        the ``truth.*`` key when it cannot be built)."""
        base, platform, lengths, thetas = params.geometric_errors()
        real = mech.with_offsets(np.asarray(mech.base_offsets) + base,
                                 np.asarray(mech.platform_offsets) + platform)
        try:
            model = build(params.clearance, real, payload, structure)
        except ParameterError as err:
            raise err.within('truth.') from None
        return cls(real, model, lengths, thetas,
                   effects=Effects.from_parameters(params, real, payload, structure))


def settled(change: float, previous: float, tolerance: float) -> bool:
    """Whether a fixed-point iteration whose last round changed its iterate by ``change`` (the
    round before by ``previous``; inf: no round before) is within ``tolerance`` of its fixed
    point: the change itself, or once two rounds give the contraction's rate r = change /
    previous < 1, the error r / (1 - r) * change that rate leaves (the Newton iterations' test
    of scipy.integrate's implicit solvers, Hairer & Wanner, Solving ODEs II, IV.8 eq. 8.10).
    The truth's effects move the joints by micrometres over millimetres of pose, so r is about
    1e-2 and a stream's second round (a change of 1e-10 to 7e-10) leaves 1e-12 to 6e-12: one
    round a pose fewer than waiting for the change itself to fall below the tolerance."""
    if change <= tolerance:
        return True
    if not (math.isfinite(previous) and previous > 0.0):
        return False
    rate = change / previous
    return rate < 1.0 and rate / (1.0 - rate) * change <= tolerance


def _true_conditions(conditions: Conditions | ModelConditions | None, n: int) -> Conditions:
    """The true conditions of N samples from the truth's own, the cell's view of them (its
    air temperature for the legs' too), or none (20 °C, approach unknown)."""
    if conditions is None:
        return Conditions.reference(n)
    if isinstance(conditions, Conditions):
        return conditions
    air = REFERENCE_TEMPERATURE + conditions.temperature_change(n, REFERENCE_TEMPERATURE)
    return Conditions(air, np.repeat(air[:, None], 3, axis=1), conditions.approach_signs(n))


def truth_from_params(params: Mapping[str, Any], mech: Mechanism,
                      payload: Payload | None = None,
                      structure: Structure | None = None) -> Truth:
    """The truth from a ``truth:`` block (nested or dotted keys, relative to it or prefixed
    ``truth.``) over the nominal ``mech`` (:class:`TruthParameters`); ConfigError names a bad
    key."""
    flat = flatten(params)
    if any(k.startswith('truth.') for k in flat):
        flat = block(flat, 'truth')
    return Truth.from_parameters(parse(TruthParameters, flat, 'truth.'), mech, payload,
                                 structure)
