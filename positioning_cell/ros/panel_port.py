"""The coordinated cell as the panel's calibration drives it
(:class:`~positioning_cell.procedures.panel_calibration.PanelPort`), through a
:class:`~positioning_cell.ros.client.CellClient`: the cell coordinator's panel move (action
MoveToPose, cell frame) and the cell tracker's readings of the panel
(/panel/metrology/pose)."""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from numpy.typing import ArrayLike, NDArray
from positioning_cell_interfaces.action import MoveToPose
from positioning_cell_interfaces.msg import MoveCommand

from positioning_cell import names
from positioning_cell.polling import wait_until
from positioning_cell.procedures.port import Moved, ProcedureError
from positioning_cell.ros.client import CellClient, GoalClient
from positioning_cell.ros.messages import pose_arrays, pose_stamped, seconds
from positioning_cell.ros.qos import STREAM_QOS

FloatArray = NDArray[np.float64]

#: Readings kept (20 Hz: a minute).
HISTORY = 1200


class RosPanelPort:
    """The panel on ``client``'s graph; ``timeout`` s for readings and for the coordinator to
    answer, ``move_timeout`` s for a panel move's result (past it the move is cancelled: every
    positioner stops). A context manager (its exit closes the action client)."""

    def __init__(self, client: CellClient, timeout: float = 30.0,
                 move_timeout: float = 120.0) -> None:
        self.client, self.timeout, self.move_timeout = client, timeout, move_timeout
        self._lock = threading.Lock()
        self._readings: deque[tuple[float, FloatArray, FloatArray]] = deque(maxlen=HISTORY)
        client.node.create_subscription(PoseWithCovarianceStamped, names.PANEL_MEASURED_POSE,
                                        self._on_pose, STREAM_QOS)
        self.goals = GoalClient(client, MoveToPose, names.COORDINATED_MOVE_ACTION)

    def _on_pose(self, msg: Any) -> None:
        if msg.header.frame_id != names.CELL_FRAME:
            return  # not the panel in the cell frame
        p, q = pose_arrays(msg.pose.pose)
        with self._lock:
            self._readings.append((seconds(msg.header.stamp), p, q))

    def ready(self) -> None:
        """Wait for the coordinator's panel move (TimeoutError after ``timeout``)."""
        self.goals.ready(self.timeout)

    def now(self) -> float:
        return float(self.client.node.get_clock().now().nanoseconds * 1e-9)

    def move_panel(self, position: ArrayLike, quaternion: ArrayLike,
                   speed_scale: float = 0.0) -> Moved:
        command = MoveCommand(mode=MoveCommand.ABSOLUTE, speed_scale=float(speed_scale))
        command.pose = pose_stamped(position, quaternion, self.client.node.get_clock().now()
                                    .to_msg(), names.CELL_FRAME)
        try:
            handle = self.goals.send(MoveToPose.Goal(command=command), timeout=self.timeout)
        except TimeoutError as err:
            return Moved(False, '', str(err))
        if not handle.accepted:
            return Moved(False, 'refused', 'the cell coordinator refused the goal')
        try:
            outcome = self.goals.result(handle, self.move_timeout).result.outcome
        except TimeoutError as err:
            # a move that does not end in time is stopped: the cancel stops every positioner
            with contextlib.suppress(TimeoutError):
                self.goals.cancel(handle, self.timeout)
            return Moved(False, '', f'{err}; the panel move cancelled')
        return Moved(outcome.code == 0, str(outcome.code_name), str(outcome.reason))

    def panel_readings(self, count: int, since: float | None = None
                       ) -> tuple[FloatArray, FloatArray]:
        start = self.now() if since is None else since

        def taken() -> list[tuple[float, FloatArray, FloatArray]]:
            with self._lock:
                return [r for r in self._readings if r[0] >= start]

        try:
            wait_until(lambda: len(taken()) >= count, self.timeout,
                       f'{count} readings on {names.PANEL_MEASURED_POSE}')
        except TimeoutError as err:
            raise ProcedureError(str(err)) from err
        first = sorted(taken(), key=lambda r: r[0])[:count]
        return np.array([r[1] for r in first]), np.array([r[2] for r in first])

    def __enter__(self) -> RosPanelPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.goals.close()
