"""The validity bitmask of a check: one bit per constraint, as Symétrie controllers return a
validity bitmask on every check, with the words for people and the signed margins (SI) that
go with it.

The bits are those of the ROS message that carries a check (same constants). The factory
layer is the mechanism's own limits (:mod:`positioning_cell.core.limits`); the machine and user
layers are boxes in pose6 (:mod:`positioning_cell.limits.boxes`); the state bits say why
nothing may move now, whatever the pose.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntFlag
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.limits import (
    LimitReport,
    Violation,
    check_poses,
    limit_values,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.moves.outcomes import ResultCode

FloatArray = NDArray[np.float64]


class Validity(IntFlag):
    """One bit per reason a pose or a command is not valid (0: valid). The values are those of
    the ROS message; never renumber them."""

    WORKSPACE = 1  # no pose: unreachable, the inverse kinematics fails
    STROKE = 2  # a leg length outside length_min..length_max
    PHI = 4  # a first (passive) U angle outside phi_min..phi_max
    THETA = 8  # a second (actuated) U angle outside theta_min..theta_max
    SPHERICAL_TILT = 16  # a spherical joint tilted beyond tilt_max
    LEG_DISTANCE = 32  # two legs closer than min_leg_distance
    SINGULARITY = 64  # conditioning below the singularity margin
    MACHINE_LIMITS = 128  # outside the machine box (machine CS)
    USER_LIMITS = 256  # outside the user box (user CS)
    NOT_REFERENCED = 512  # the drives are not referenced
    DRIVES_OFF = 1024  # the drives are disabled
    INVALID_GOAL = 2048  # a malformed request (NaN, bad frame, bad tolerance...)
    BUSY = 4096  # a command is running
    DRIVE_FAULT = 8192  # a drive is in fault
    DRIVER_SILENT = 16384  # no encoder readings (or no pose estimate), drives not connected
    TRACKER_SILENT = 32768  # no tracker readings while the measured mode needs them


#: The empty mask: valid.
VALID = Validity(0)

#: The bits of the mechanism's own limits (the factory layer).
FACTORY_BITS = (Validity.WORKSPACE | Validity.STROKE | Validity.PHI | Validity.THETA
                | Validity.SPHERICAL_TILT | Validity.LEG_DISTANCE | Validity.SINGULARITY)
#: The bits of a pose: the factory layer and the machine and user boxes.
POSE_BITS = FACTORY_BITS | Validity.MACHINE_LIMITS | Validity.USER_LIMITS
#: The bits of the state of the machine and of the request, whatever the pose.
STATE_BITS = (Validity.NOT_REFERENCED | Validity.DRIVES_OFF | Validity.INVALID_GOAL
              | Validity.BUSY | Validity.DRIVE_FAULT | Validity.DRIVER_SILENT
              | Validity.TRACKER_SILENT)

#: Every bit.
ALL_BITS = POSE_BITS | STATE_BITS

#: The bit of each constraint name of :mod:`positioning_cell.core.limits`, in the order of
#: :func:`positioning_cell.core.limits.limit_values`.
CONSTRAINT_BITS: Mapping[str, Validity] = MappingProxyType({
    'length_min': Validity.STROKE,
    'length_max': Validity.STROKE,
    'phi_min': Validity.PHI,
    'phi_max': Validity.PHI,
    'theta_min': Validity.THETA,
    'theta_max': Validity.THETA,
    'spherical_tilt': Validity.SPHERICAL_TILT,
    'leg_distance_min': Validity.LEG_DISTANCE,
    'conditioning_min': Validity.SINGULARITY,
})

#: The result code of a refusal for each bit, in the order the positioner refuses (busy, a
#: malformed goal, the drives, referencing, then the limits of the pose).
_REFUSALS = (
    (Validity.BUSY, ResultCode.REFUSED_BUSY),
    (Validity.INVALID_GOAL, ResultCode.REFUSED_INVALID_GOAL),
    (Validity.DRIVES_OFF, ResultCode.REFUSED_DRIVES_OFF),
    (Validity.DRIVE_FAULT, ResultCode.REFUSED_DRIVE_FAULT),
    (Validity.DRIVER_SILENT, ResultCode.REFUSED_DRIVER_SILENT),
    (Validity.NOT_REFERENCED, ResultCode.REFUSED_NOT_REFERENCED),
    (Validity.TRACKER_SILENT, ResultCode.REFUSED_TRACKER_SILENT),
    (POSE_BITS, ResultCode.REFUSED_LIMITS),
)


def bit_of(constraint: str) -> Validity:
    """The bit of a constraint name of :mod:`positioning_cell.core.limits` (ValueError for a
    name without one: a new constraint must get its bit here)."""
    try:
        return CONSTRAINT_BITS[constraint]
    except KeyError:
        raise ValueError(f'no validity bit for the constraint {constraint!r}') from None


def bits_of(report: LimitReport) -> Validity:
    """The bits of the violations a report lists. A report lists at most 50 violations
    (``n_violations`` may be more): for a long path use :func:`factory_check`, whose bits
    come from every sample."""
    bits = VALID
    for v in report.violations:
        bits |= bit_of(v.constraint)
    return bits


def bit_names(bits: int) -> tuple[str, ...]:
    """The lower-case names of the bits set in ``bits``, lowest bit first."""
    return tuple((b.name or '').lower() for b in Validity if int(bits) & int(b))


def result_code(bits: int) -> ResultCode:
    """The result code of a check with these bits: SUCCESS when none is set, else the refusal
    the positioner gives first (busy, invalid goal, drives off, drive fault, not referenced,
    limits)."""
    mask = Validity(bits)
    for bit, code in _REFUSALS:
        if mask & bit:
            return code
    return ResultCode.SUCCESS


@dataclass(frozen=True)
class CheckResult:
    """A check: ``bits`` set, one line per violation for people (each names its layer:
    'factory: ...', 'machine limits: ...', 'user limits: ...', 'state: ...'),
    and signed margins by name in SI (m, rad or dimensionless; positive: inside by that much,
    negative: violated; names prefixed by the layer, e.g. 'factory.length_max',
    'machine.Tz'). A set bit always has a line, and a line a bit (InputError otherwise)."""

    bits: Validity = VALID
    violations: tuple[str, ...] = ()
    margins: Mapping[str, float] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        try:
            number = int(self.bits)
        except (TypeError, ValueError) as err:
            raise InputError(f'bits = {self.bits!r}: not a validity bitmask') from err
        if number < 0 or number & ~int(ALL_BITS):
            raise InputError(f'bits = {number}: not a validity bitmask (bits of Validity only)')
        bits = Validity(number)
        lines = tuple(str(v) for v in self.violations)
        if bool(bits) != bool(lines):
            raise InputError(f'bits = {int(bits)} with {len(lines)} violation lines: a set bit '
                             'needs a line saying why, and a line a bit')
        object.__setattr__(self, 'bits', bits)
        object.__setattr__(self, 'violations', lines)
        object.__setattr__(self, 'margins', MappingProxyType(
            {str(k): float(v) for k, v in self.margins.items()}))

    @property
    def valid(self) -> bool:
        """True when no bit is set."""
        return self.bits == VALID

    @property
    def code(self) -> ResultCode:
        """The result code of this check (:func:`result_code`)."""
        return result_code(self.bits)

    def merged(self, *others: CheckResult) -> CheckResult:
        """One result of several checks: bits or-ed, lines in order, each margin the smallest
        of those given under its name."""
        bits, lines = self.bits, list(self.violations)
        margins = dict(self.margins)
        for other in others:
            bits |= other.bits
            lines += other.violations
            for name, value in other.margins.items():
                margins[name] = min(margins.get(name, math.inf), value)
        return CheckResult(bits, tuple(lines), margins)

    def message(self, most: int = 3) -> str:
        """Words for a refusal: the first ``most`` lines and how many more."""
        if self.valid:
            return 'valid'
        more = len(self.violations) - most
        tail = f' (+{more} more)' if more > 0 else ''
        return '; '.join(self.violations[:most]) + tail


def _margin_arrays(mech: Mechanism, p: FloatArray,
                   q: FloatArray) -> list[tuple[str, FloatArray]]:
    """Per constraint, the signed margin of every sample (N,), SI: the worst leg or pair; a
    value that is not finite (no pose) counts as -inf."""
    if p.shape[0] == 0:
        raise InputError('no poses to check (N = 0)')
    try:
        return _margins_of(mech, p, q)
    except (np.linalg.LinAlgError, FloatingPointError):
        pass
    # A degenerate pose (a leg of zero length...) fails the whole batch: one pose at a time,
    # a pose that fails has no finite value at all.
    rows = []
    for i in range(p.shape[0]):
        try:
            rows.append(np.array([m[0] for _, m in _margins_of(mech, p[i:i + 1],
                                                                q[i:i + 1])]))
        except (np.linalg.LinAlgError, FloatingPointError):
            rows.append(np.full(len(CONSTRAINT_BITS), -np.inf))
    table = np.stack(rows)
    return [(name, table[:, j]) for j, name in enumerate(CONSTRAINT_BITS)]


def _margins_of(mech: Mechanism, p: FloatArray,
                q: FloatArray) -> list[tuple[str, FloatArray]]:
    out = []
    with np.errstate(all='ignore'):  # what is not finite is no pose: -inf
        for name, value, limit, sign, _ in limit_values(mech, p, q):
            margin = sign * (limit - value)
            margin = np.where(np.isfinite(margin), margin, -np.inf)
            out.append((name, margin.min(axis=1)))
    return out


def factory_margins(mech: Mechanism, position: ArrayLike,
                    quaternion: ArrayLike) -> dict[str, float]:
    """For each constraint of :mod:`positioning_cell.core.limits` (``length_min``,
    ``length_max``, ..., ``conditioning_min``) the smallest signed margin over the poses
    (N, 3) m / (N, 4) x, y, z, w and their legs, SI (m, rad, dimensionless): positive inside
    by that much, negative violated (-inf: no pose). InputError for malformed input."""
    p, q = as_pose_batch(position, quaternion)
    return {name: float(m.min()) for name, m in _margin_arrays(mech, p, q)}


def factory_check(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> CheckResult:
    """The factory layer of poses (N, 3) m / (N, 4): the mechanism's limits at every sample.
    The bits come from every sample (WORKSPACE where the inverse kinematics gives no finite
    value), the lines from :func:`positioning_cell.core.limits.check_poses` ('factory: sample
    3: leg 1 length ...'), the margins are :func:`factory_margins` as 'factory.<name>'."""
    p, q = as_pose_batch(position, quaternion)
    per_sample = _margin_arrays(mech, p, q)
    bits = VALID
    lines: list[str] = []
    lost = np.zeros(p.shape[0], dtype=bool)
    for name, margin in per_sample:
        lost |= margin == -np.inf
        if np.any((margin < 0.0) & np.isfinite(margin)):
            bits |= bit_of(name)
    if lost.any():
        bits |= Validity.WORKSPACE
        samples = np.flatnonzero(lost)
        more = f' (+{samples.size - 1} more samples)' if samples.size > 1 else ''
        lines.append(f'factory: sample {int(samples[0])}: no pose, the inverse kinematics '
                     f'fails{more}')
    if int(bits) & ~int(Validity.WORKSPACE):
        # per violated constraint its worst sample, and how many samples violate it
        for name, margin in per_sample:
            bad = (margin < 0.0) & np.isfinite(margin)
            if not bad.any():
                continue
            worst = int(np.flatnonzero(bad)[np.argmin(margin[bad])])
            report = check_poses(mech, p[worst:worst + 1], q[worst:worst + 1])
            found = [v for v in report.violations if v.constraint == name]
            count = int(bad.sum())
            tail = (f' (the worst of {count} of {p.shape[0]} samples outside)' if count > 1
                    else '')
            lines += [f'factory: {_renumbered(v, worst).describe()}{tail}' for v in found]
    margins = {f'factory.{name}': float(m.min()) for name, m in per_sample}
    return CheckResult(bits, tuple(lines), margins)


def _renumbered(v: Violation, sample: int) -> Violation:
    return dataclasses.replace(v, sample=sample)


def state_check(*, referenced: bool = True, drives_enabled: bool = True,
                drive_fault: str | None = None, busy: bool = False) -> CheckResult:
    """The state layer: what forbids motion now whatever the pose ('state: ...' lines);
    ``drive_fault`` is the drive's fault message (None: no fault)."""
    found: list[tuple[Validity, str]] = []
    if not referenced:
        found.append((Validity.NOT_REFERENCED, 'state: the axes are not referenced (home them '
                                               'first)'))
    if not drives_enabled:
        found.append((Validity.DRIVES_OFF, 'state: the drives are disabled'))
    if drive_fault is not None:
        found.append((Validity.DRIVE_FAULT, f'state: drive fault: {drive_fault}'))
    if busy:
        found.append((Validity.BUSY, 'state: busy, a command is in progress'))
    bits = VALID
    for bit, _ in found:
        bits |= bit
    return CheckResult(bits, tuple(line for _, line in found))


def invalid_goal(reason: str) -> CheckResult:
    """A malformed request: INVALID_GOAL with the reason ('state: invalid goal: ...')."""
    return CheckResult(Validity.INVALID_GOAL, (f'state: invalid goal: {reason}',))


def factory_constraints(mech: Mechanism) -> list[str]:
    """The factory layer's limits of a mechanism, one line each, mm and deg."""
    def deg(value: float) -> str:
        return f'{math.degrees(value):.3f} deg'

    return [
        f'stroke: leg length {mech.length_min * 1e3:.3f} .. {mech.length_max * 1e3:.3f} mm',
        f'phi (first, passive U angle): {deg(mech.phi_min)} .. {deg(mech.phi_max)}',
        f'theta (second, actuated U angle): {deg(mech.theta_min)} .. {deg(mech.theta_max)}',
        f'spherical-joint tilt: at most {deg(mech.tilt_max)}',
        f'distance between legs: at least {mech.min_leg_distance * 1e3:.3f} mm',
        f'singularity margin: conditioning at least {mech.min_conditioning:g}',
    ]
