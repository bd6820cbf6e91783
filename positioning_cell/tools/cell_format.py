"""The pure half of the operator's client ``cell`` (:mod:`positioning_cell.tools.cell`): the
command line, the requests it makes of the cell (SI, from the operator's mm and degrees), the
exit codes, and what it prints (one text for people, one JSON object for scripts). No ROS:
the ROS half turns these values into messages and back.

Six human numbers for a pose are Tx, Ty, Tz mm and Rx, Ry, Rz deg with R = Rz·Ry·Rx
(:mod:`positioning_cell.frames.transforms`); every SI value in a JSON document is m, rad, s.

JSON documents (:func:`json_text`): one object per command, always with ``command``,
``exit_code``, ``exit_name`` (its label in :mod:`positioning_cell.tools.exits`) and ``error``
(null, or why the command failed), and the fields of
that command; a NaN or an infinite number is written as null (an unknown uncertainty, an
unlimited bound). A pose is an object with ``position_m`` (3), ``quaternion_xyzw`` (4),
``pose6`` (Tx, Ty, Tz m, Rx, Ry, Rz rad) and ``human`` (mm, deg); the last two are null for a
pose whose quaternion is not a rotation.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import (
    OBJECT_FRAME,
    USER_FRAME,
    CoordinateSystems,
)
from positioning_cell.frames.transforms import (
    MM_PER_M,
    Transform,
    human_from_pose6,
    pq_from_pose6,
)
from positioning_cell.limits.axis_ranges import AxisRanges
from positioning_cell.limits.speed import Speeds
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.tools.cell_parser import (  # the command line: there, light
    MODE_ABSOLUTE,
    MODE_NAMES,
    MODE_RELATIVE_OBJECT,
    MODE_RELATIVE_USER,
    NO_LIMIT,
    human_pose,
)
from positioning_cell.tools.exits import Exit

FloatArray = NDArray[np.float64]

# -- exit codes (the one table: :mod:`positioning_cell.tools.exits`) -----------------------------
#: MoveOutcome's numbering (its .msg): the ranges of refusals and aborts.
_REFUSED_CODES = range(10, 30)
_ABORTED_CODES = range(30, 50)
_OUT_OF_TOLERANCE_CODE = 50


def exit_code(code_name: str, code: int | None = None) -> Exit:
    """The exit code of a move's or a homing's outcome: by ``code_name`` (a
    :class:`~positioning_cell.moves.outcomes.ResultCode` value, MoveOutcome's lower-case
    constant name), else by the number ``code`` in MoveOutcome's ranges; an outcome that is
    neither (a newer positioner's, or none) counts as aborted."""
    try:
        result = ResultCode(code_name)
    except ValueError:
        result = None
    if result is ResultCode.SUCCESS:
        return Exit.OK
    if result is ResultCode.OUT_OF_TOLERANCE:
        return Exit.NOT_ACHIEVED
    if result is not None:
        return Exit.REFUSED if result.refused else Exit.ABORTED
    if code is None:
        return Exit.ABORTED
    if code == 0:
        return Exit.OK
    if code == _OUT_OF_TOLERANCE_CODE:
        return Exit.NOT_ACHIEVED
    return Exit.REFUSED if code in _REFUSED_CODES else Exit.ABORTED


# -- numbers and poses ---------------------------------------------------------------------------
#: The heading of the live axis ranges (status, check; the watch's table too).
AXIS_RANGES_TITLE = 'axis ranges (each user axis with the other five held; mm, deg)'
#: The six pose components with their human units.
AXES_HUMAN = ('Tx mm', 'Ty mm', 'Tz mm', 'Rx deg', 'Ry deg', 'Rz deg')
#: Decimals of human output: mm (0.1 µm) and degrees.
MM_DECIMALS = 4
DEG_DECIMALS = 5


def finite(value: float) -> float | None:
    """``value`` as a float, None if NaN or infinite (JSON has neither)."""
    v = float(value)
    return v if math.isfinite(v) else None


def plain(value: Any) -> Any:
    """``value`` with numpy scalars and arrays as Python numbers and lists, tuples as lists,
    and every NaN or infinite float as None: what :func:`json.dumps` takes strictly."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return finite(float(value))
    return value


def json_text(doc: Mapping[str, Any]) -> str:
    """One JSON object on one line (NaN and infinities as null, :func:`plain`)."""
    return json.dumps(plain(doc), allow_nan=False, ensure_ascii=False)


def human_text(human: ArrayLike) -> str:
    """Six human numbers as ``'Tx Ty Tz mm Rx Ry Rz deg'``, 0.1 µm and 1e-5° resolution."""
    h = np.asarray(human, dtype=float)
    t = ' '.join(f'{v:{MM_DECIMALS + 6}.{MM_DECIMALS}f}' for v in h[:3])
    r = ' '.join(f'{v:{DEG_DECIMALS + 5}.{DEG_DECIMALS}f}' for v in h[3:])
    return f'{t} mm {r} deg'


def si_from_human(human: ArrayLike) -> FloatArray:
    """SI six numbers (m, rad) of human ones (mm, deg); infinities stay infinite (bounds)."""
    h = np.asarray(human, dtype=float).reshape(6)
    return np.concatenate([h[:3] / MM_PER_M, np.radians(h[3:])])


def human_from_si(pose6: ArrayLike) -> FloatArray:
    """Human six numbers (mm, deg) of SI ones (m, rad); infinities stay infinite (bounds)."""
    v = np.asarray(pose6, dtype=float).reshape(6)
    return np.concatenate([v[:3] * MM_PER_M, np.degrees(v[3:])])


def transform_of(position: ArrayLike, quaternion: ArrayLike) -> Transform | None:
    """The transform of a position (3,) m and quaternion (4,) x, y, z, w; None if they are
    not a pose (a zero or non-finite quaternion, e.g. a field a refusal left empty)."""
    try:
        return Transform.from_pq(position, quaternion)
    except InputError:
        return None


def transform_document(t: Transform | None) -> dict[str, Any] | None:
    """A pose document (module docstring) of a transform; None for None."""
    if t is None:
        return None
    p, q = t.to_pq()
    pose6 = t.to_pose6()
    return {'position_m': p, 'quaternion_xyzw': q, 'pose6': pose6,
            'human': human_from_pose6(pose6)}


def pose_document(position: ArrayLike, quaternion: ArrayLike) -> dict[str, Any]:
    """A pose document (module docstring) of a position (3,) m and a quaternion (4,) as
    given; ``pose6`` and ``human`` null if the quaternion is not a rotation."""
    p = np.asarray(position, dtype=float).reshape(3)
    q = np.asarray(quaternion, dtype=float).reshape(4)
    t = transform_of(p, q)
    pose6 = None if t is None else t.to_pose6()
    return {'position_m': p, 'quaternion_xyzw': q, 'pose6': pose6,
            'human': None if pose6 is None else human_from_pose6(pose6)}


def transform_text(t: Transform | None) -> str:
    """A transform in human numbers; ``'unknown'`` for None."""
    return 'unknown' if t is None else human_text(t.to_human())


# -- requests ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MoveRequest:
    """A MoveCommand in SI: ``mode`` (MODE_*), the ``frame`` of ``pose6`` (Tx, Ty, Tz m, Rx,
    Ry, Rz rad), the settle ``tolerance`` (m; 0: the configured one) and ``speed_scale``
    (0: 1)."""

    mode: int
    frame: str
    pose6: FloatArray
    tolerance: float = 0.0
    speed_scale: float = 0.0

    @property
    def position(self) -> FloatArray:
        """The pose's position (3,) m."""
        return pq_from_pose6(self.pose6)[0]

    @property
    def quaternion(self) -> FloatArray:
        """The pose's unit quaternion (4,) x, y, z, w (w ≥ 0)."""
        return pq_from_pose6(self.pose6)[1]

    def document(self) -> dict[str, Any]:
        """The request for JSON: mode (number and name), frame, the pose, tolerance m,
        speed scale."""
        return {'mode': self.mode, 'mode_name': MODE_NAMES[self.mode], 'frame': self.frame,
                'pose': pose_document(self.position, self.quaternion),
                'tolerance_m': self.tolerance, 'speed_scale': self.speed_scale}


def move_request(args: argparse.Namespace) -> MoveRequest:
    """The MoveRequest of parsed ``move`` or ``check`` arguments (mm → m, deg → rad)."""
    human = human_pose(args)
    if args.relative_user:
        mode, frame = MODE_RELATIVE_USER, USER_FRAME
    elif args.relative_object:
        mode, frame = MODE_RELATIVE_OBJECT, OBJECT_FRAME
    else:
        mode, frame = MODE_ABSOLUTE, args.frame
    return MoveRequest(mode, frame, si_from_human(human), args.tolerance / MM_PER_M,
                       0.0 if args.speed_scale is None else args.speed_scale)


def frames_request(args: argparse.Namespace) -> tuple[Transform | None, Transform | None]:
    """The user and object CS of ``frames set`` (None: keep the current one)."""
    user = None if args.user is None else Transform.from_human(args.user)
    obj = None if args.object is None else Transform.from_human(args.object)
    return user, obj


def jog_request(args: argparse.Namespace) -> tuple[str, float]:
    """The axis and the SI step (m for a length, rad for an angle) of ``jog``."""
    return args.axis, jog_si(args.axis, args.delta)


def is_length(axis: str) -> bool:
    """Is ``axis`` (a JOINT_NAMES entry) a leg length (else an angle)?"""
    if axis not in JOINT_NAMES:
        raise InputError(f'axis {axis!r} is not one of {", ".join(JOINT_NAMES)}')
    return JOINT_NAMES.index(axis) < 3


def jog_si(axis: str, delta: float) -> float:
    """A jog step in SI: mm → m for a length, deg → rad for an angle."""
    return delta / MM_PER_M if is_length(axis) else math.radians(delta)


def jog_human(axis: str, value: float) -> float:
    """An axis value in human units: m → mm for a length, rad → deg for an angle."""
    return value * MM_PER_M if is_length(axis) else math.degrees(value)


def jog_unit(axis: str) -> str:
    """The human unit of ``axis``."""
    return 'mm' if is_length(axis) else 'deg'


def speeds_document(speeds: Speeds) -> dict[str, Any]:
    """Speeds and accelerations (SI; 0 in a request: keep that one) with their human values,
    for JSON."""
    return {'linear_speed_m_s': speeds.linear_speed,
            'angular_speed_rad_s': speeds.angular_speed,
            'linear_acceleration_m_s2': speeds.linear_acceleration,
            'angular_acceleration_rad_s2': speeds.angular_acceleration,
            'linear_speed_mm_s': speeds.linear_speed * MM_PER_M,
            'angular_speed_deg_s': math.degrees(speeds.angular_speed),
            'linear_acceleration_mm_s2': speeds.linear_acceleration * MM_PER_M,
            'angular_acceleration_deg_s2': math.degrees(speeds.angular_acceleration)}


def speed_request(args: argparse.Namespace) -> Speeds:
    """The SetSpeed request of ``speed`` (mm → m, deg → rad; an option left out: 0, keep)."""
    def si(value: float | None, linear: bool) -> float:
        if value is None:
            return 0.0
        return value / MM_PER_M if linear else math.radians(value)

    return Speeds(si(args.linear, True), si(args.angular, False),
                       si(args.linear_acceleration, True), si(args.angular_acceleration, False))


#: A box: lower (6,) and upper (6,) SI bounds (±inf: none).
Box = tuple[FloatArray, FloatArray]


def box_of(lower: ArrayLike, upper: ArrayLike) -> Box:
    """A box of SI bounds."""
    return (np.asarray(lower, dtype=float).reshape(6), np.asarray(upper, dtype=float).reshape(6))


@dataclass(frozen=True)
class LimitBoxes:
    """What ``limits set`` gives, human (mm, deg) and None where left out; NaN in a bound:
    no limit (``none`` on the command line)."""

    machine_lower: Sequence[float] | None = None
    machine_upper: Sequence[float] | None = None
    user_lower: Sequence[float] | None = None
    user_upper: Sequence[float] | None = None

    def merged(self, machine: Box, user: Box) -> tuple[Box, Box]:
        """The machine and user boxes (SI) to set: these bounds where given, ``machine`` and
        ``user`` (the current ones, SI) elsewhere."""
        def side(given: Sequence[float] | None, current: FloatArray, sign: float) -> FloatArray:
            if given is None:
                return np.array(current, dtype=float)
            h = np.array(given, dtype=float)
            h[np.isnan(h)] = sign * math.inf
            return si_from_human(h)

        return ((side(self.machine_lower, machine[0], -1.0),
                 side(self.machine_upper, machine[1], 1.0)),
                (side(self.user_lower, user[0], -1.0), side(self.user_upper, user[1], 1.0)))


def limits_request(args: argparse.Namespace) -> LimitBoxes:
    """The bounds of ``limits set``."""
    return LimitBoxes(args.machine_lower, args.machine_upper, args.user_lower, args.user_upper)


# -- outcomes of moves and homing -----------------------------------------------------------------
@dataclass(frozen=True)
class Outcome:
    """A MoveOutcome in plain values: ``code`` and ``code_name``, ``reason``, where the
    platform ended (whatever the code; a refusal: where it stands): the platform pose (in
    ``attained_frame``) and object pose in the user CS (positions (3,) m, quaternions (4,) x,
    y, z, w), the errors against the goal (Δp (3,) m, rotation vector (3,) rad; NaN: no valid
    goal) and their standard uncertainty (6,) (NaN: unknown), and ``attained_source``:
    ``measured`` (the tracker), ``estimated`` (the encoders through the model) or empty (not
    known: the poses mean nothing)."""

    code: int
    code_name: str
    reason: str
    attained_frame: str = ''
    attained_position: FloatArray = field(default_factory=lambda: np.zeros(3))
    attained_quaternion: FloatArray = field(default_factory=lambda: np.array([0., 0., 0., 1.]))
    user_position: FloatArray = field(default_factory=lambda: np.zeros(3))
    user_quaternion: FloatArray = field(default_factory=lambda: np.array([0., 0., 0., 1.]))
    position_error: FloatArray = field(default_factory=lambda: np.zeros(3))
    orientation_error: FloatArray = field(default_factory=lambda: np.zeros(3))
    uncertainty: FloatArray = field(default_factory=lambda: np.full(6, np.nan))
    attained_source: str = ''

    @property
    def exit_code(self) -> Exit:
        """Its exit code (:func:`exit_code`)."""
        return exit_code(self.code_name, self.code)

    @property
    def moved(self) -> bool:
        """Not refused: the machine may have moved."""
        return self.exit_code != Exit.REFUSED

    @property
    def known(self) -> bool:
        """The attained poses mean something (they have a source)."""
        return bool(self.attained_source)

    @property
    def position_error_um(self) -> float:
        """|Δp|, µm."""
        return float(np.linalg.norm(self.position_error) * 1e6)

    @property
    def orientation_error_deg(self) -> float:
        """The rotation angle of the error, deg."""
        return math.degrees(float(np.linalg.norm(self.orientation_error)))

    def document(self) -> dict[str, Any]:
        """Every field for JSON (uncertainty: null where unknown)."""
        attained = pose_document(self.attained_position, self.attained_quaternion)
        known = self.known
        return {'code': self.code, 'code_name': self.code_name, 'reason': self.reason,
                'attained_source': self.attained_source or None,
                'attained': {'frame': self.attained_frame, **attained} if known else None,
                'attained_user': (pose_document(self.user_position, self.user_quaternion)
                                  if known else None),
                'position_error_m': self.position_error,
                'orientation_error_rad': self.orientation_error,
                'position_error_um': self.position_error_um,
                'orientation_error_deg': self.orientation_error_deg,
                'uncertainty': self.uncertainty}

    def text(self) -> str:
        """For people: code and reason; where the platform ended (labelled measured or
        estimated; "not known" without a source), the error against the goal (if there was a
        valid one) and its uncertainty (when known). A refusal says nothing moved."""
        head = f'{self.code_name or "no outcome"} ({self.code})'
        lines = [f'{head}: {self.reason}' if self.reason else head]
        where = 'standing at' if not self.moved else 'ended at'
        if not self.known:
            lines.append(f'  {where}: not known (no pose estimate, no tracker reading)')
            return '\n'.join(lines)
        user = transform_of(self.user_position, self.user_quaternion)
        lines.append(f'  user position  {transform_text(user)}  ({self.attained_source}'
                     + (', nothing moved)' if not self.moved else ')'))
        if np.isfinite(self.position_error).all():
            lines.append(f'  error          {self.position_error_um:.1f} µm, '
                         f'{self.orientation_error_deg:.{DEG_DECIMALS}f} deg')
        u = np.asarray(self.uncertainty, dtype=float)
        if np.isfinite(u).any():
            lines.append(f'  uncertainty    {_uncertainty_text(u)} (1σ)')
        return '\n'.join(lines)


def _uncertainty_text(u: FloatArray) -> str:
    def num(v: float, scale: float, decimals: int) -> str:
        return f'{v * scale:.{decimals}f}' if math.isfinite(v) else '?'

    t = ' '.join(num(v, 1e6, 1) for v in u[:3])
    r = ' '.join(num(v, 180.0 / math.pi, DEG_DECIMALS) for v in u[3:])
    return f'x y z {t} µm, rx ry rz {r} deg'


@dataclass
class GoalRun:
    """How a goal (a move, a homing) went: accepted (None: no answer), the outcome (None: none
    came, ``error`` says why and ``code`` is the exit code), the goal status of the result,
    whether it was cancelled and why ('interrupt' or 'timeout')."""

    accepted: bool | None = None
    outcome: Outcome | None = None
    goal_status: int | None = None
    cancelled: bool = False
    cancel_cause: str | None = None
    error: str | None = None
    code: Exit = Exit.ABORTED

    @property
    def exit_code(self) -> Exit:
        """The outcome's exit code, else :attr:`code`."""
        return self.code if self.outcome is None else self.outcome.exit_code

    def fields(self) -> dict[str, Any]:
        """Its fields in the command's JSON document."""
        return {'accepted': self.accepted, 'cancelled': self.cancelled,
                'cancel_cause': self.cancel_cause, 'goal_status': self.goal_status,
                'outcome': None if self.outcome is None else self.outcome.document()}

    def text(self) -> str:
        """Its text for people."""
        lines = []
        if self.cancelled:
            cause = 'Ctrl-C' if self.cancel_cause == 'interrupt' else '--timeout'
            lines.append(f'cancelled ({cause})')
        if self.outcome is not None:
            lines.append(self.outcome.text())
        return '\n'.join(lines)


def jog_exit_code(success: bool, code_name: str) -> Exit:
    """The exit code of a jog: 0 on success, else that of its code name if it is a refusal or
    an abort, else refused."""
    if success:
        return Exit.OK
    code = exit_code(code_name)
    return code if code_name in _RESULT_NAMES and code != Exit.OK else Exit.REFUSED


_RESULT_NAMES = frozenset(r.value for r in ResultCode)


def progress_line(phase_name: str, progress: float, position_error: ArrayLike | None = None,
                  width: int = 30) -> str:
    """One line of progress: phase, a bar of ``width`` for ``progress`` (0..1), the percentage
    and, when given, |Δp| in µm."""
    p = min(max(float(progress), 0.0), 1.0) if math.isfinite(progress) else 0.0
    filled = round(p * width)
    line = f'{phase_name or "...":<10} [{"#" * filled}{"." * (width - filled)}] {p * 100:3.0f}%'
    if position_error is not None:
        dp = float(np.linalg.norm(np.asarray(position_error, dtype=float))) * 1e6
        if math.isfinite(dp):
            line += f'  |Δp| {dp:.1f} µm'
    return line


# -- check ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CheckReport:
    """A CheckPose response in plain values: valid, the validity bits and their names, one
    line per violation, the margins (SI, negative: violated by that much), the goal resolved
    to the platform in ``goal_frame`` and the planned duration (s)."""

    valid: bool
    bits: int
    bit_names: Sequence[str]
    violations: Sequence[str]
    margin_names: Sequence[str]
    margins: Sequence[float]
    goal_frame: str
    goal_position: FloatArray
    goal_quaternion: FloatArray
    duration: float
    axis_ranges: AxisRanges | None = None

    @property
    def exit_code(self) -> Exit:
        """0 if valid, else refused."""
        return Exit.OK if self.valid else Exit.REFUSED

    def document(self) -> dict[str, Any]:
        """Every field for JSON."""
        return {'valid': self.valid, 'bits': self.bits, 'bit_names': list(self.bit_names),
                'violations': list(self.violations),
                'margins': [{'name': n, 'value': v}
                            for n, v in zip(self.margin_names, self.margins, strict=False)],
                'goal': {'frame': self.goal_frame,
                         **pose_document(self.goal_position, self.goal_quaternion)},
                'duration_s': self.duration,
                'axis_ranges': (None if self.axis_ranges is None
                                else self.axis_ranges.document())}

    def text(self) -> str:
        """For people: valid and the duration, or the violated constraints and each
        violation; then the margins and the axis ranges from the goal."""
        if self.valid:
            goal = transform_of(self.goal_position, self.goal_quaternion)
            lines = [f'valid: the move takes {self.duration:.2f} s',
                     f'  goal ({self.goal_frame or "base"})  {transform_text(goal)}']
        else:
            lines = [f'not valid (bits {self.bits}): {", ".join(self.bit_names) or "?"}']
            lines += [f'  - {v}' for v in self.violations]
        if self.margin_names:
            lines.append('margins (SI; negative: violated):')
            width = max(len(n) for n in self.margin_names)
            lines += [f'  {n:<{width}}  {v:.6g}'
                      for n, v in zip(self.margin_names, self.margins, strict=False)]
        if self.axis_ranges is not None:
            lines.append(f'{AXIS_RANGES_TITLE} from the goal:')
            lines += [f'  {line}' for line in self.axis_ranges.lines()]
        return '\n'.join(lines)


# -- coordinate systems, limits, speeds -----------------------------------------------------------
class SystemNames(NamedTuple):
    """The named coordinate systems as GetCoordinateSystems gives them: the active name and
    every stored name of each kind."""

    active_user: str
    active_object: str
    user_names: Sequence[str]
    object_names: Sequence[str]


def systems_document(systems: CoordinateSystems, file: str = '',
                     named: SystemNames | None = None) -> dict[str, Any]:
    """The active user and object CS for JSON (and the file they are kept in, and the named
    systems when given)."""
    doc: dict[str, Any] = {'user': transform_document(systems.user),
                           'object': transform_document(systems.object), 'file': file}
    if named is not None:
        doc |= {'active_user': named.active_user, 'active_object': named.active_object,
                'user_names': list(named.user_names),
                'object_names': list(named.object_names)}
    return doc


def systems_text(systems: CoordinateSystems, file: str = '',
                 named: SystemNames | None = None) -> str:
    """The active user and object CS for people (with their names and the stored ones when
    ``named`` is given)."""
    user = '' if named is None else f' {named.active_user!r}'
    obj = '' if named is None else f' {named.active_object!r}'
    lines = [f'user CS{user} (in machine)'.ljust(25) + transform_text(systems.user),
             f'object CS{obj} (in platform)'.ljust(25) + transform_text(systems.object)]
    if named is not None:
        lines.append(f'stored                   user: {", ".join(named.user_names)}; '
                     f'object: {", ".join(named.object_names)}')
    if file:
        lines.append(f'file                     {file}')
    return '\n'.join(lines)


def _bound_text(value: float, decimals: int) -> str:
    return f'{value:.{decimals}f}' if math.isfinite(value) else NO_LIMIT


def box_document(box: Box) -> dict[str, Any]:
    """A box for JSON: SI and human bounds (null: no limit)."""
    return {'lower': box[0], 'upper': box[1], 'lower_human': human_from_si(box[0]),
            'upper_human': human_from_si(box[1])}


def limits_document(factory: Box, machine: Box, user: Box,
                    constraints: Sequence[str] = ()) -> dict[str, Any]:
    """The three boxes and the factory's mechanism limits for JSON."""
    return {'factory': box_document(factory), 'machine': box_document(machine),
            'user': box_document(user), 'factory_constraints': list(constraints)}


def limits_text(factory: Box, machine: Box, user: Box, constraints: Sequence[str] = ()) -> str:
    """The three boxes as a table (mm, deg; "none": no limit), then the factory's mechanism
    limits."""
    head = '               ' + ' '.join(f'{a:>11}' for a in AXES_HUMAN)
    lines = [head]
    for name, box in (('factory', factory), ('machine', machine), ('user', user)):
        for side, bound in (('lower', box[0]), ('upper', box[1])):
            h = human_from_si(bound)
            cells = [_bound_text(v, 3 if i < 3 else 4) for i, v in enumerate(h)]
            lines.append(f'{name:<8} {side:<5} ' + ' '.join(f'{c:>11}' for c in cells))
    if constraints:
        lines.append('factory mechanism limits:')
        lines += [f'  {c}' for c in constraints]
    return '\n'.join(lines)


def speeds_text(current: Speeds, maximum: Speeds) -> str:
    """Current speeds and accelerations with their maxima, mm and deg."""
    rows = (('linear speed', current.linear_speed, maximum.linear_speed, 'mm/s', True),
            ('angular speed', current.angular_speed, maximum.angular_speed, 'deg/s', False),
            ('linear acceleration', current.linear_acceleration, maximum.linear_acceleration,
             'mm/s²', True),
            ('angular acceleration', current.angular_acceleration,
             maximum.angular_acceleration, 'deg/s²', False))
    out = []
    for name, now, top, unit, linear in rows:
        scale = MM_PER_M if linear else 180.0 / math.pi
        out.append(f'{name:<21} {now * scale:10.3f} {unit:<6} (max {top * scale:.3f})')
    return '\n'.join(out)


# -- status --------------------------------------------------------------------------------------
def parse_bool(text: str | None) -> bool | None:
    """A diagnostic value as a boolean: true/false (any case), 1/0, yes/no; None otherwise."""
    if text is None:
        return None
    word = text.strip().lower()
    if word in ('true', '1', 'yes', 'on'):
        return True
    if word in ('false', '0', 'no', 'off'):
        return False
    return None


#: A pose: position (3,) m and quaternion (4,) x, y, z, w, as received.
PoseValues = tuple[ArrayLike, ArrayLike]


class MeasuredValues(NamedTuple):
    """A tracker reading for ``status``: the platform pose in base, its standard uncertainty
    (6,) (x, y, z m, rot-x, rot-y, rot-z rad) and the time it measured (s since the epoch, the
    cell's clock; NaN: not stamped)."""

    pose: PoseValues
    uncertainty: FloatArray
    stamp: float


@dataclass(frozen=True)
class StatusReport:
    """What ``status`` gathered: the positioner's diagnostic values (state, reason, mode, code,
    referenced) and message, the leg driver's (enabled, state; None if none came), the
    target and the estimated platform pose in base (None if none came), the tracker's newest
    reading (None if none came) and ``now`` (s since the epoch) to tell its age, the
    coordinate systems and the mechanism (for the machine CS; None if unknown) and why
    something is unknown."""

    positioner: Mapping[str, str]
    positioner_message: str = ''
    positioner_level: int = 0
    driver: Mapping[str, str] | None = None
    target: PoseValues | None = None
    estimate: PoseValues | None = None
    systems: CoordinateSystems | None = None
    systems_file: str = ''
    mechanism: Mechanism | None = None
    notes: Sequence[str] = ()
    measured: MeasuredValues | None = None
    now: float = math.nan
    axis_ranges: AxisRanges | None = None

    @property
    def measured_age(self) -> float | None:
        """How old the tracker's reading is, s (None: no reading, or not stamped)."""
        if self.measured is None or not math.isfinite(self.measured.stamp):
            return None
        return self.now - self.measured.stamp

    @property
    def referenced(self) -> bool | None:
        return parse_bool(self.positioner.get('referenced'))

    @property
    def drives_enabled(self) -> bool | None:
        return None if self.driver is None else parse_bool(self.driver.get('enabled'))

    def positions(self, pose: PoseValues | None) -> dict[str, Transform | None]:
        """A platform pose in base as the base, machine and user poses (None: unknown)."""
        t = None if pose is None else transform_of(*pose)
        if t is None:
            return {'base': None, 'machine': None, 'user': None}
        p, q = t.to_pq()
        machine = user = None
        if self.mechanism is not None:
            machine = CoordinateSystems.machine_from_base(p, q, self.mechanism)
            if self.systems is not None:
                user = self.systems.user_position(p, q, self.mechanism)
        return {'base': t, 'machine': machine, 'user': user}

    def document(self) -> dict[str, Any]:
        """Every field for JSON: state, reason, mode, code, referenced, drives, positions by
        frame (user, machine, base) and kind (target, estimated), the coordinate systems, the
        raw diagnostic values."""
        kinds = {'target': self.positions(self.target),
                 'estimated': self.positions(self.estimate),
                 'measured': self.positions(None if self.measured is None
                                            else self.measured.pose)}
        return {
            'state': self.positioner.get('state', ''),
            'reason': self.positioner.get('reason', ''),
            'mode': self.positioner.get('mode', ''),
            'code': self.positioner.get('code', ''),
            'last_code': self.positioner.get('last_code', ''),
            'last_reason': self.positioner.get('last_reason', ''),
            'calibration': self.positioner.get('calibration', ''),
            'measured_age_s': self.measured_age,
            'measured_uncertainty': (None if self.measured is None
                                     else self.measured.uncertainty),
            'referenced': self.referenced,
            'drives_enabled': self.drives_enabled,
            'driver_state': None if self.driver is None else self.driver.get('state'),
            'level': self.positioner_level,
            'message': self.positioner_message,
            'positions': {frame: {kind: transform_document(poses[frame])
                                  for kind, poses in kinds.items()}
                          for frame in ('user', 'machine', 'base')},
            'coordinate_systems': (None if self.systems is None
                                   else systems_document(self.systems, self.systems_file)),
            'positioner_values': dict(self.positioner),
            'driver_values': None if self.driver is None else dict(self.driver),
            'axis_ranges': None if self.axis_ranges is None else self.axis_ranges.document(),
            'notes': list(self.notes),
        }

    def text(self) -> str:
        """For people: state and reason, the flags, then the positions."""
        def yes(value: bool | None) -> str:
            return '?' if value is None else ('yes' if value else 'no')

        v = self.positioner
        driver_state = '' if self.driver is None else self.driver.get('state', '')
        last = v.get('last_code') or v.get('code') or '-'
        last_reason = v.get('last_reason', '')
        lines = [f'state       {v.get("state", "?")}' + (f': {v["reason"]}'
                                                         if v.get('reason') else ''),
                 f'mode        {v.get("mode", "?")}',
                 f'last code   {last}' + (f': {last_reason}'
                                          if last_reason and last_reason != v.get('reason')
                                          else ''),
                 f'calibration {v.get("calibration") or "?"}',
                 f'referenced  {yes(self.referenced)}',
                 f'drives      enabled {yes(self.drives_enabled)}'
                 + (f' ({driver_state})' if driver_state else '')]
        target, estimate = self.positions(self.target), self.positions(self.estimate)
        measured = self.positions(None if self.measured is None else self.measured.pose)
        if v.get('user_cs_name'):
            lines.append(f'systems     user {v["user_cs_name"]!r}, object '
                         f'{v.get("object_cs_name", "?")!r}')
        lines.append('positions   (Tx Ty Tz mm, Rx Ry Rz deg)')
        for frame in ('user', 'machine'):
            lines.append(f'  {frame:<8} target     {transform_text(target[frame])}')
            lines.append(f'  {"":<8} estimated  {transform_text(estimate[frame])}')
            lines.append(f'  {"":<8} measured   {transform_text(measured[frame])}')
        if self.measured is not None:
            age = self.measured_age
            lines.append('measured    by the tracker, '
                         + ('not stamped' if age is None else f'{age:.2f} s ago')
                         + f'; uncertainty {_uncertainty_text(self.measured.uncertainty)} '
                         '(1σ)')
        if self.axis_ranges is not None:
            lines.append(f'{AXIS_RANGES_TITLE} from the current user position:')
            lines += [f'  {line}' for line in self.axis_ranges.lines()]
        lines += [f'note: {n}' for n in self.notes]
        return '\n'.join(lines)


# -- documents of every command ------------------------------------------------------------------
def command_document(command: str, code: Exit, error: str | None = None,
                     fields: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The JSON document of ``command``: command, exit_code, exit_name, error, then
    ``fields`` (which cannot replace those four)."""
    doc: dict[str, Any] = dict(fields or {})
    doc.update(command=command, exit_code=int(code), exit_name=Exit(code).label, error=error)
    return {k: doc[k] for k in ('command', 'exit_code', 'exit_name', 'error')} | {
        k: v for k, v in doc.items() if k not in ('command', 'exit_code', 'exit_name', 'error')}
