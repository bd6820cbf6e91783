"""What ``cell`` (:mod:`positioning_cell.tools.cell`) sends and reads, without rclpy: the
messages of its plain values (:mod:`positioning_cell.tools.cell_format`, SI) and back, and the
goal loop over an action client's futures (progress, a cancel on an interrupt or the timeout).
The client that makes the calls: :mod:`positioning_cell.ros.operator_client`."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from positioning_cell_interfaces.msg import BoxLimits, MoveCommand, MoveOutcome
from positioning_cell_interfaces.msg import CoordinateSystems as SystemsMsg

from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.ros import operator_messages as om
from positioning_cell.ros.messages import pose_arrays, pose_stamped
from positioning_cell.tools import cell_format as cf
from positioning_cell.tools.exits import Exit

#: After a cancel: how long the result (or the goal's acceptance) may take (s).
CANCEL_WAIT = 30.0
#: Polling period of a running goal, and of the progress bar (s).
POLL = 0.05


# -- messages <-> the plain values ----------------------------------------------------------------
def move_command(request: cf.MoveRequest, stamp: Time | None = None) -> MoveCommand:
    """The MoveCommand of a request (SI, quaternion x, y, z, w; the pose's frame_id the
    request's frame)."""
    command = MoveCommand(mode=int(request.mode), tolerance=float(request.tolerance),
                          speed_scale=float(request.speed_scale))
    command.pose = pose_stamped(request.position, request.quaternion, stamp or Time(),
                                request.frame)
    return command


def outcome_of(msg: MoveOutcome) -> cf.Outcome:
    """A MoveOutcome as plain values."""
    p, q = pose_arrays(msg.attained.pose)
    up, uq = pose_arrays(msg.attained_user)
    return cf.Outcome(int(msg.code), str(msg.code_name), str(msg.reason),
                      str(msg.attained.header.frame_id), p, q, up, uq,
                      np.asarray(msg.position_error, dtype=float).reshape(3),
                      np.asarray(msg.orientation_error, dtype=float).reshape(3),
                      np.asarray(msg.uncertainty, dtype=float).reshape(6),
                      str(msg.attained_source))


def check_of(response: Any) -> cf.CheckReport:
    """A CheckPose response as plain values."""
    v = response.validity
    p, q = pose_arrays(response.goal.pose)
    return cf.CheckReport(bool(response.valid), int(v.bits), [str(n) for n in v.bit_names],
                          [str(t) for t in v.violations], [str(n) for n in v.margin_names],
                          [float(m) for m in v.margins], str(response.goal.header.frame_id),
                          p, q, float(response.duration),
                          om.axis_ranges(response.axis_ranges)[0])


def systems_of(msg: SystemsMsg) -> CoordinateSystems:
    """The library's coordinate systems of a CoordinateSystems message."""
    return CoordinateSystems(user=om.transform(msg.user), object=om.transform(msg.object))


def box_of(msg: BoxLimits) -> cf.Box:
    """A BoxLimits message as (lower, upper) arrays (m, rad)."""
    return cf.box_of(msg.lower, msg.upper)


def box_msg(box: cf.Box) -> BoxLimits:
    """The BoxLimits message of (lower, upper)."""
    return BoxLimits(lower=[float(v) for v in box[0]], upper=[float(v) for v in box[1]])


# -- goals (actions) ------------------------------------------------------------------------------
def drive(goals: Any, goal: Any, timeout: float, interrupts: Callable[[], int],
          note: Callable[[str], None], progress: Callable[[Any], None]) -> cf.GoalRun:
    """Send ``goal`` on ``goals`` (a :class:`GoalClient` whose server is ready) and wait for
    its result, passing each feedback to ``progress``. An interrupt (``interrupts()`` grows:
    the caller counts SIGINT and SIGTERM) or ``timeout`` s cancel the goal, a controlled stop
    (``note`` says so); then the result is awaited CANCEL_WAIT s more, and a second interrupt
    gives up waiting."""
    run = cf.GoalRun()
    latest: list[Any] = [None]
    start = interrupts()
    send = goals.action.send_goal_async(goal, feedback_callback=lambda m: latest.__setitem__(
        0, m.feedback))
    deadline = time.monotonic() + timeout
    handle: Any = None
    result: Any = None
    cancel_at: float | None = None
    while True:
        now = time.monotonic()
        if handle is None and send.done():
            handle = send.result()
            run.accepted = bool(handle.accepted)
            if not handle.accepted:
                run.error, run.code = 'the positioner rejected the goal', Exit.REFUSED
                return run
            result = handle.get_result_async()
        if result is not None and result.done():
            _take_result(run, result.result())
            return run
        count = interrupts() - start
        if count >= 2:
            run.error, run.code = ('interrupted again: the result of the cancelled goal was '
                                   'not awaited'), Exit.INTERRUPTED
            return run
        if run.cancel_cause is None and (count or now > deadline):
            run.cancel_cause = 'interrupt' if count else 'timeout'
            cancel_at = now
            note('cancelling the goal (a controlled stop); Ctrl-C again: do not wait'
                 if count else f'no result within {timeout:g} s: cancelling the goal (a '
                 'controlled stop)')
        if run.cancel_cause is not None and handle is not None and not run.cancelled:
            handle.cancel_goal_async()
            run.cancelled = True
        if cancel_at is not None and now > cancel_at + CANCEL_WAIT:
            what = 'the goal\'s acceptance' if handle is None else 'the result'
            run.error = f'{what} did not come within {CANCEL_WAIT:g} s of the cancel'
            run.code = Exit.NOT_THERE
            return run
        if latest[0] is not None:
            progress(latest[0])
        goals.spin_once(POLL)  # the answers and feedback, taken by this thread only


def _take_result(run: cf.GoalRun, response: Any) -> None:
    run.goal_status = int(response.status)
    outcome = response.result.outcome
    if not outcome.code_name:
        run.error = f'the positioner gave no outcome (goal status {run.goal_status})'
        run.code = Exit.ABORTED
        return
    run.outcome = outcome_of(outcome)


def move_progress(feedback: Any) -> str:
    return cf.progress_line(str(feedback.phase_name), float(feedback.progress),
                            np.asarray(feedback.position_error, dtype=float))


def home_progress(feedback: Any) -> str:
    return cf.progress_line(str(feedback.phase_name), float(feedback.progress))
