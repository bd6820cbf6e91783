"""calibrator_node (node ``calibrator``): the Calibrate action runs the live calibration.

The action on /calibrator/calibrate runs
:func:`positioning_cell.procedures.calibration.calibrate` on the running cell through a
:class:`~positioning_cell.ros.port.RosCellPort` (a client node of its own in this node's
context, for the goal), in a worker thread (:func:`positioning_cell.ros.goals.run_goal`):
feedback per measured pose, the identification's figures in the result, the
positioner told to load the file (``load``). One goal at a time (another one meanwhile is
rejected); a cancel, or the node's shutdown, stops the move at once (/positioner/stop), puts
the positioner's mode back and writes nothing."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from positioning_cell_interfaces.action import Calibrate
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from positioning_cell import names
from positioning_cell.calibration.settings import CalibratorSettings
from positioning_cell.errors import ConfigError
from positioning_cell.motion.settings import machine_settings
from positioning_cell.procedures.calibration import Outcome, calibrate
from positioning_cell.procedures.stopping import Stopped
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.goals import OneGoal, Ran, run_goal
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.qos_watch import QosWatchedNode
from positioning_cell.ros.spin import NodeStart, Spin

#: Longest wait at shutdown for a running calibration to stop the drives, put the mode back
#: and end, s (it ends as soon as the stopped move has ended).
CLOSE_WAIT_S = 10.0


class CalibratorNode(QosWatchedNode):
    """The ``calibrator`` node (module docstring)."""

    NAME = names.NODE_CALIBRATOR
    SETTINGS = CalibratorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS)
        self.machine = machine_settings(self.params.settings.machine_file())
        self._goal = OneGoal(self.get_logger(), 'calibration')
        self._server = ActionServer(self, Calibrate, names.CALIBRATE_ACTION, self._execute,
                                    goal_callback=self._goal.accept,
                                    cancel_callback=lambda _: CancelResponse.ACCEPT,
                                    callback_group=ReentrantCallbackGroup())

    def _execute(self, goal_handle: Any) -> Calibrate.Result:
        with self._goal.running():
            return self._calibrate(goal_handle)

    def _calibrate(self, goal_handle: Any) -> Calibrate.Result:
        goal = goal_handle.request
        try:
            settings = self.params.settings.for_goal(goal.poses, goal.hold_out, goal.samples)
        except ConfigError as err:
            goal_handle.abort()
            return Calibrate.Result(success=False, reason=f'invalid goal: {err}')
        ran = run_goal(goal_handle, lambda stop, feedback: self._work(settings, stop, feedback),
                       closing=self._goal.closing)
        return self._finish(goal_handle, ran)

    def _work(self, settings: CalibratorSettings, stop: threading.Event,
              feedback: Callable[[Any], None]) -> Outcome:
        """The calibration, in the goal's worker thread, through a client node of its own
        in this node's context (spun in the client's thread)."""
        with CellClient(name=f'{self.NAME}_client', context=self.context, stop=stop) as client:
            return calibrate(
                RosCellPort(client), self.machine, settings.program,
                settings.samples, Path(settings.out_dir), self._say, load=settings.load,
                timeout=settings.timeout, stop=stop,
                progress=lambda k, total, which, deviation: feedback(Calibrate.Feedback(
                    pose=k, poses=total, set_name=which, deviation=deviation)))

    def _say(self, text: str) -> None:
        self.get_logger().info(text)

    def _finish(self, goal_handle: Any, ran: Ran[Outcome]) -> Calibrate.Result:
        """End the goal by how the calibration ended: succeeded (written, and loaded if
        asked), canceled (a requested stop), else aborted with the reason."""
        outcome = ran.value
        if outcome is None:
            if isinstance(ran.error, Stopped):
                why = 'canceled' if ran.canceled else 'stopped (the node shuts down)'
                reason = f'{why}: drives stopped, nothing written'
            else:
                reason = f'{type(ran.error).__name__}: {ran.error}'
                self.get_logger().error(f'calibration failed: {reason}')
            if ran.canceled:
                goal_handle.canceled()
            else:
                goal_handle.abort()
            return Calibrate.Result(success=False, reason=reason)
        result = Calibrate.Result(success=outcome.succeeded, reason=outcome.reason,
                                  calibration_file=str(outcome.path.resolve())
                                  if outcome.path is not None else '')
        if outcome.figures is not None:
            result.fit_rms = outcome.figures.fit_rms
            result.hold_out_rms = outcome.figures.hold_out_rms
            result.identified = outcome.figures.identified
        if outcome.succeeded:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def close(self) -> None:
        """At shutdown: a running calibration is stopped (drives stopped, the positioner's
        mode put back, nothing written) before the node goes."""
        self._goal.close(CLOSE_WAIT_S)


#: The entry point of ``calibrator_node`` (alone; ``cell_container`` hosts it with others).
main = NodeStart(CalibratorNode, Spin.THREADS, threads=3)


if __name__ == '__main__':
    raise SystemExit(main())
