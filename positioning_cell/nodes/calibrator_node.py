"""calibrator_node (node ``calibrator``): the Calibrate action on /calibrator/calibrate runs
``calibrate_cell``'s live calibration (:func:`positioning_cell.tools.calibrate_cell.
calibrate_live`) on the running cell, in a worker thread with its own client of the cell:
feedback per measured pose, the identification's figures in the result, the positioner told
to load the file (``load``). One goal at a time (another one meanwhile is rejected); a cancel
stops the move (/positioner/stop), puts the positioner's mode back and writes nothing."""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any

from positioning_cell_interfaces.action import Calibrate
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.calibration.settings import CalibratorSettings
from positioning_cell.errors import ConfigError
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.spin import Spin, run
from positioning_cell.tools.calibrate_cell import (
    EXIT_OK,
    InterruptedRunError,
    Machine,
    Outcome,
    calibrate_live,
)

#: How often the goal's thread looks for a cancel and passes the feedback on, s.
POLL_S = 0.1
#: Longest wait at shutdown for a running calibration to stop the drives and end, s.
CLOSE_WAIT_S = 10.0


class CalibratorNode(Node):
    """The ``calibrator`` node (module docstring)."""

    NAME = names.NODE_CALIBRATOR
    SETTINGS = CalibratorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS)
        self.machine = Machine.from_config(self.params.settings.machine_file())
        self._lock = threading.Lock()
        self._busy = False
        self._closing = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._server = ActionServer(self, Calibrate, names.CALIBRATE_ACTION, self._execute,
                                    goal_callback=self._on_goal,
                                    cancel_callback=lambda _: CancelResponse.ACCEPT,
                                    callback_group=ReentrantCallbackGroup())

    def _on_goal(self, goal: Any) -> GoalResponse:
        """One calibration at a time: a goal while one runs (or at shutdown) is rejected."""
        with self._lock:
            if self._busy or self._closing.is_set():
                self.get_logger().warning('Calibrate goal rejected: ' + (
                    'the node shuts down' if self._closing.is_set()
                    else 'a calibration is running'))
                return GoalResponse.REJECT
            self._busy = True
            self._idle.clear()
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle: Any) -> Calibrate.Result:
        try:
            return self._calibrate(goal_handle)
        finally:
            with self._lock:
                self._busy = False
                self._idle.set()

    def _calibrate(self, goal_handle: Any) -> Calibrate.Result:
        goal = goal_handle.request
        try:
            settings = self.params.settings.for_goal(goal.poses, goal.hold_out, goal.samples)
        except ConfigError as err:
            goal_handle.abort()
            return Calibrate.Result(success=False, reason=f'invalid goal: {err}')
        stop = threading.Event()
        feedback: queue.SimpleQueue[tuple[int, int, str, float]] = queue.SimpleQueue()
        box: dict[str, Any] = {}
        worker = threading.Thread(target=self._work, args=(settings, stop, feedback, box),
                                  daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(POLL_S)
            if goal_handle.is_cancel_requested or self._closing.is_set():
                stop.set()
            self._pass_on(goal_handle, feedback)
        self._pass_on(goal_handle, feedback)
        return self._finish(goal_handle, box)

    def _work(self, settings: CalibratorSettings, stop: threading.Event,
              feedback: queue.SimpleQueue[tuple[int, int, str, float]],
              box: dict[str, Any]) -> None:
        """The calibration, in its own thread with its own client of the cell (a context of
        its own on this node's domain, spun in the client's thread)."""
        try:
            with CellClient(self.context.get_domain_id(), f'{self.NAME}_client',
                            signals=False) as client:
                box['outcome'] = calibrate_live(
                    client, self.machine, settings.program, settings.samples,
                    Path(settings.out_dir), self._say, load=settings.load,
                    timeout=settings.timeout, stop=stop,
                    progress=lambda *pose: feedback.put(pose))
        except InterruptedRunError:
            box['interrupted'] = True
        except Exception as err:  # reported in the result; the node goes on serving
            self.get_logger().error(f'calibration failed: {type(err).__name__}: {err}')
            box['error'] = f'{type(err).__name__}: {err}'

    def _say(self, text: str) -> None:
        self.get_logger().info(text)

    @staticmethod
    def _pass_on(goal_handle: Any, feedback: queue.SimpleQueue[tuple[int, int, str, float]]
                 ) -> None:
        """Publish the measured poses reported so far as feedback."""
        while not feedback.empty():
            k, total, which, deviation = feedback.get()
            goal_handle.publish_feedback(Calibrate.Feedback(
                pose=k, poses=total, set_name=which, deviation=deviation))

    def _finish(self, goal_handle: Any, box: dict[str, Any]) -> Calibrate.Result:
        """End the goal by how the calibration ended: succeeded (written, and loaded if
        asked), canceled (a requested stop), else aborted with the reason."""
        outcome: Outcome | None = box.get('outcome')
        if outcome is None:
            canceled = 'interrupted' in box and goal_handle.is_cancel_requested
            stopped = 'canceled' if canceled else 'stopped (the node shuts down)'
            reason = box.get('error', f'{stopped}: drives stopped, nothing written')
            if canceled:
                goal_handle.canceled()
            else:
                goal_handle.abort()
            return Calibrate.Result(success=False, reason=reason)
        success = outcome.status == EXIT_OK and outcome.loaded is not False
        result = Calibrate.Result(success=success, reason=outcome.reason,
                                  calibration_file=str(outcome.path.resolve())
                                  if outcome.path is not None else '')
        if outcome.figures is not None:
            result.fit_rms = outcome.figures.fit_rms
            result.hold_out_rms = outcome.figures.hold_out_rms
            result.identified = outcome.figures.identified
        if success:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def close(self) -> None:
        """At shutdown: a running calibration is stopped (drives stopped, the positioner's
        mode put back, nothing written) before the node goes."""
        self._closing.set()
        self._idle.wait(CLOSE_WAIT_S)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``calibrator_node``."""
    return run(CalibratorNode, args, Spin.THREADS, threads=3)


if __name__ == '__main__':
    raise SystemExit(main())
