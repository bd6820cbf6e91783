"""positioning_cell_interfaces messages ↔ the library's types of the operator's surface: move
requests, outcomes, validity, coordinate systems, limit boxes, speeds, axis ranges."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from geometry_msgs.msg import Pose
from positioning_cell_interfaces.msg import (
    AxisRanges as AxisRangesMsg,
)
from positioning_cell_interfaces.msg import (
    BoxLimits as BoxLimitsMsg,
)
from positioning_cell_interfaces.msg import (
    CoordinateSystems as CoordinateSystemsMsg,
)
from positioning_cell_interfaces.msg import (
    MoveCommand as MoveCommandMsg,
)
from positioning_cell_interfaces.msg import (
    MoveOutcome,
    Validity,
)
from positioning_cell_interfaces.msg import (
    Speeds as SpeedsMsg,
)

from positioning_cell.core.poses import (
    as_unit_quaternions,
    quaternion_from_rotation_vector,
    quaternion_product,
)
from positioning_cell.frames.systems import ABSOLUTE, RELATIVE_OBJECT, RELATIVE_USER
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.axis_ranges import AxisRange, AxisRanges
from positioning_cell.limits.boxes import BoxLimits
from positioning_cell.limits.speed import Speeds
from positioning_cell.limits.validity import CheckResult
from positioning_cell.moves.correction import deviation
from positioning_cell.moves.outcomes import Attained, MoveResult, ResultCode
from positioning_cell.ros.messages import pose_arrays, pose_msg, seconds, start_of, vector_of
from positioning_cell.ros.outcome_codes import CODES

if TYPE_CHECKING:
    from positioning_cell.motion.controller import MoveCommand

#: MoveCommand.mode ↔ the library's move kinds.
KINDS = {MoveCommandMsg.ABSOLUTE: ABSOLUTE, MoveCommandMsg.RELATIVE_USER: RELATIVE_USER,
         MoveCommandMsg.RELATIVE_OBJECT: RELATIVE_OBJECT}


def move_command(msg: MoveCommandMsg) -> MoveCommand:
    """The library's request of a MoveCommand (an unknown mode is an invalid kind, named)."""
    # Only the positioner converts commands (it has the controller loaded already); the
    # operator's client, which imports this module too, does not load the motion layer.
    from positioning_cell.motion.controller import MoveCommand

    p, q = pose_arrays(msg.pose.pose)
    return MoveCommand(KINDS.get(msg.mode, f'mode {msg.mode}'), msg.pose.header.frame_id, p, q,
                       float(msg.tolerance), float(msg.speed_scale), float(msg.duration),
                       start_of(msg.start), vector_of(msg.pivot))


def attained(result: MoveResult, goal: tuple[Any, Any]) -> tuple[Any, Any]:
    """The attained platform pose in base: the goal (p, q) ⊕ the result's error (Δp, and the
    rotation vector of R_goalᵀ·R_attained)."""
    p = np.asarray(goal[0]) + np.asarray(result.position_error)
    q = quaternion_product(as_unit_quaternions(goal[1], 'goal quaternion')[0],
                           quaternion_from_rotation_vector(result.orientation_error))
    return p, q


def outcome(code: ResultCode, reason: str, result: MoveResult | None = None,
            goal: tuple[Any, Any] | None = None, user: Transform | None = None,
            stamp: Any = None, where: Attained | None = None) -> MoveOutcome:
    """A MoveOutcome: the code and its words, and where the platform ended: for a settled
    move's ``result`` the goal (p, q in base) ⊕ its attained error; else ``where`` (a move
    that did not settle: :meth:`Mover.attained_now`, or the pose it was judged on), its error
    against ``goal`` when there is one (else NaN). With the pose's source, the error's standard
    uncertainty (NaN when unknown) and the attained object frame in the user CS ``user``.
    Neither: the pose fields stay zero, ``attained_source`` empty and the errors NaN."""
    out = MoveOutcome(code=CODES[code], code_name=code.value, reason=reason)
    out.uncertainty = [math.nan] * 6
    out.position_error, out.orientation_error = [math.nan] * 3, [math.nan] * 3
    errors: tuple[Any, Any] | None = None
    if result is not None and goal is not None:
        where = Attained(*attained(result, goal), result.source, result.uncertainty)
        errors = (result.position_error, result.orientation_error)
    elif where is not None and goal is not None:
        errors = deviation(where.position, where.quaternion, *goal)
    if where is not None:
        out.attained.header.frame_id = 'base'
        if stamp is not None:
            out.attained.header.stamp = stamp
        out.attained.pose = pose_msg(where.position, where.quaternion)
        out.attained_source = where.source
        if where.uncertainty is not None:
            out.uncertainty = [float(v) for v in where.uncertainty]
    if errors is not None:
        out.position_error = [float(v) for v in np.asarray(errors[0])]
        out.orientation_error = [float(v) for v in np.asarray(errors[1])]
    if user is not None:
        out.attained_user = pose_msg(*user.to_pq())
    return out


def validity(result: CheckResult) -> Validity:
    """The Validity message of a check."""
    names = sorted(result.margins)
    return Validity(bits=int(result.bits),
                    bit_names=[(b.name or '').lower() for b in type(result.bits)
                               if result.bits & b],
                    violations=list(result.violations), margin_names=names,
                    margins=[float(result.margins[n]) for n in names])


def transform(pose: Pose) -> Transform:
    """A geometry_msgs/Pose as a Transform (InputError: NaN, a non-unit quaternion)."""
    return Transform.from_pq(*pose_arrays(pose))


def systems_msg(user: Transform, obj: Transform) -> CoordinateSystemsMsg:
    """The CoordinateSystems message of the user and object frames."""
    return CoordinateSystemsMsg(user=pose_msg(*user.to_pq()), object=pose_msg(*obj.to_pq()))


def box(msg: BoxLimitsMsg) -> BoxLimits:
    """A BoxLimits message as the library's box (InputError naming a bad bound)."""
    return BoxLimits(tuple(float(v) for v in msg.lower), tuple(float(v) for v in msg.upper))


def box_msg(limits: BoxLimits) -> BoxLimitsMsg:
    """The BoxLimits message of a box."""
    return BoxLimitsMsg(lower=[float(v) for v in limits.lower],
                        upper=[float(v) for v in limits.upper])


def speeds(msg: SpeedsMsg) -> Speeds:
    """A Speeds message as the library's speeds."""
    return Speeds(msg.linear_speed, msg.angular_speed, msg.linear_acceleration,
                  msg.angular_acceleration)


def speeds_msg(value: Speeds) -> SpeedsMsg:
    """The Speeds message of the library's speeds."""
    return SpeedsMsg(linear_speed=value.linear_speed, angular_speed=value.angular_speed,
                     linear_acceleration=value.linear_acceleration,
                     angular_acceleration=value.angular_acceleration)


def axis_ranges_msg(ranges: AxisRanges, user_cs: str, stamp: Any) -> AxisRangesMsg:
    """The AxisRanges message of the axis ranges of a user position in the user CS named
    ``user_cs``, stamped ``stamp`` (builtin_interfaces/Time)."""
    found = ranges.ranges
    return AxisRangesMsg(stamp=stamp, valid=ranges.valid, reason=ranges.reason,
                         pending=ranges.pending,
                         user_cs=user_cs, pose=[float(v) for v in ranges.pose],
                         axes=[r.axis for r in found], low=[float(r.low) for r in found],
                         high=[float(r.high) for r in found],
                         low_binding=[r.low_binding for r in found],
                         high_binding=[r.high_binding for r in found])


def axis_ranges(msg: AxisRangesMsg) -> tuple[AxisRanges, str, float]:
    """An AxisRanges message as the library's axis ranges, the user CS's name and the stamp
    (s)."""
    found = tuple(AxisRange(str(a), float(lo), float(hi), str(b_lo), str(b_hi))
                  for a, lo, hi, b_lo, b_hi in zip(msg.axes, msg.low, msg.high,
                                                   msg.low_binding, msg.high_binding,
                                                   strict=True))
    return (AxisRanges(tuple(float(v) for v in msg.pose), found, str(msg.reason),
                       bool(msg.pending)),
            str(msg.user_cs), seconds(msg.stamp))
