"""One positioner's node set as the coordinator drives it
(:class:`~positioning_cell.coordinated.coordinator.Positioner`), through a
:class:`~positioning_cell.ros.client.CellClient`: its CheckPose, its MoveToPose (sent with the
common duration and start, answered when it settles, is refused or aborts), its Stop and its
StopAlongPath, each under the set's namespace (names.in_set). The set's leg drives are heard
too (their status on its /diagnostics): drives that stop a move on their own end it for the
coordinator at once (:func:`~positioning_cell.moves.drive_stops.drives_stopped`), without
waiting for a positioner that may be too starved of the CPU to report it (in a shipped run
p2's drives stopped for a positioner silent 1.6 s, and the others ran on for a second,
loading the panel with 3 kN)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from positioning_cell_interfaces.msg import MoveCommand
from positioning_cell_interfaces.srv import CheckPose, MoveToPose, StopAlongPath
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.coordinated.coordinator import (
    Checked,
    Ended,
    FloatArray,
    PanelRequest,
    Pose,
)
from positioning_cell.limits.validity import result_code
from positioning_cell.moves.drive_stops import SILENCE_STOPS, drives_stopped
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.moves.timing import Timing
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.messages import (
    joint_values,
    pose_arrays,
    pose_stamped,
    stamp,
    status_values,
    vector3,
)
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, STREAM_QOS


class RosSetPort:
    """The positioner of set ``name`` (its namespace) on ``client``'s graph; ``timeout`` s:
    the longest wait for a check's or a stop's answer (and for the services to appear)."""

    def __init__(self, client: CellClient, name: str, timeout: float) -> None:
        self.client, self.name, self.timeout = client, name, timeout
        self._check = names.in_set(names.CHECK_POSE, name)
        self._move = names.in_set(names.MOVE_TO_POSE, name)
        self._stop = names.in_set(names.STOP, name)
        self._stop_along = names.in_set(names.STOP_ALONG_PATH, name)
        self._joint_states = names.in_set(names.JOINT_STATES, name)
        self._lock = threading.Lock()
        self._drives: dict[str, str] | None = None
        client.node.create_subscription(DiagnosticArray, names.in_set(names.DIAGNOSTICS, name),
                                        self._on_diagnostics, DIAGNOSTICS_QOS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == names.STATUS_DRIVER:
                with self._lock:
                    self._drives = {**status_values(status), 'message': status.message}

    def drives(self) -> dict[str, str] | None:
        """The set's leg drives' latest status values (with their ``message``); None before
        the first."""
        with self._lock:
            return None if self._drives is None else dict(self._drives)

    def _command(self, goal: Pose, request: PanelRequest, timing: Timing,
                 pivot: FloatArray) -> MoveCommand:
        command = MoveCommand(mode=MoveCommand.ABSOLUTE, tolerance=float(request.tolerance),
                              speed_scale=float(request.speed_scale),
                              duration=float(timing.duration), pivot=vector3(pivot))
        command.pose = pose_stamped(goal[0], goal[1], self.client.node.get_clock().now()
                                    .to_msg(), names.BASE_FRAME)
        if timing.start is not None:
            command.start = stamp(timing.start)
        return command

    def check(self, goal: Pose, request: PanelRequest, duration: float,
              pivot: FloatArray) -> Checked:
        """CheckPose of the goal; its move and stop services are found too (discovered and
        handshaken, :meth:`CellClient.service`), so that a move or a stop goes at once. A set
        that does not answer is a refusal naming it (REFUSED_DRIVER_SILENT)."""
        try:
            answer = self.client.call(CheckPose, self._check, CheckPose.Request(
                command=self._command(goal, request, Timing(duration), pivot)), self.timeout)
            self.client.service(MoveToPose, self._move, self.timeout)
            self.client.service(Trigger, self._stop, self.timeout)
            self.client.service(StopAlongPath, self._stop_along, self.timeout)
        except TimeoutError as err:
            return Checked(ResultCode.REFUSED_DRIVER_SILENT, f'no answer: {err}', 0.0)
        if answer.valid:
            return Checked(ResultCode.SUCCESS, '', float(answer.duration))
        reason = '; '.join(answer.validity.violations) or ', '.join(answer.validity.bit_names)
        return Checked(result_code(int(answer.validity.bits)), reason, 0.0)

    def move(self, goal: Pose, request: PanelRequest, timing: Timing, pivot: FloatArray
             ) -> Callable[[], Ended | None]:
        """Send the move (MoveToPose with ``timing``, about ``pivot``); the poll gives its
        outcome once it has answered, or once the set's drives have stopped it on their own
        (module docstring; their count of such stops taken as the move is sent, or at their
        first status after it), None while it runs."""
        sent = self.drives()
        since = [None if sent is None else sent.get(SILENCE_STOPS, '0')]
        future = self.client.service(MoveToPose, self._move, self.timeout).call_async(
            MoveToPose.Request(command=self._command(goal, request, timing, pivot)))

        def poll() -> Ended | None:
            if not future.done():
                drives = self.drives()
                if drives is None:
                    return None
                if since[0] is None:
                    since[0] = drives.get(SILENCE_STOPS, '0')
                stopped = drives_stopped(drives, since[0])
                return None if stopped is None else Ended(
                    stopped[0], f'its drives stopped on their own: {stopped[1]}', None)
            error = future.exception()
            if error is not None:
                return Ended(ResultCode.ABORTED_DRIVER_LOST, f'the move call failed: {error}',
                             None)
            return ended(future.result().outcome)
        return poll

    def stop(self) -> None:
        """Stop (the set's Stop service; TimeoutError when it does not answer)."""
        self.client.trigger(self._stop, self.timeout)

    def stop_along(self, start: float, duration: float) -> None:
        """Stop along the path from ``start`` (ROS time s) over ``duration`` s (the set's
        StopAlongPath; TimeoutError when it does not answer, RuntimeError when it refuses)."""
        answer = self.client.call(StopAlongPath, self._stop_along, StopAlongPath.Request(
            start=stamp(start), duration=float(duration)), self.timeout)
        if not answer.success:
            raise RuntimeError(f'{self.name}: {answer.message}')

    def load_cells(self, seconds: float) -> tuple[FloatArray, FloatArray] | None:
        """The mean encoder values and load-cell efforts (JOINT_NAMES order) of the set's
        joint states heard over ``seconds`` s; None when none come (within the set's answer
        timeout) or none carry both."""
        try:
            heard = self.client.heard_for(JointState, self._joint_states, seconds,
                                          self.timeout, STREAM_QOS)
        except TimeoutError:
            return None
        pairs = [(joint_values(msg, names.JOINT_NAMES), joint_values(msg, names.JOINT_NAMES,
                                                                     'effort'))
                 for msg in heard]
        both = [(q, tau) for q, tau in pairs if q is not None and tau is not None]
        if not both:
            return None
        return (np.mean([q for q, _ in both], axis=0), np.mean([tau for _, tau in both], axis=0))


def ended(outcome: Any) -> Ended:
    """A MoveOutcome as an :class:`Ended` (the attained pose in base when one is known)."""
    try:
        code = ResultCode(str(outcome.code_name))
    except ValueError:
        code = ResultCode.ABORTED_FAULT
    attained = pose_arrays(outcome.attained.pose) if outcome.attained_source else None
    return Ended(code, str(outcome.reason), attained)
