"""The calibrator node on the running cell (the real executables, separate processes, one
private domain per test): a Calibrate goal gives feedback for every measured pose and a
calibration the positioner loads; a cancel stops the move through /positioner/stop, puts the
positioner's mode back and writes nothing; a second goal while one runs is rejected."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from action_msgs.msg import GoalStatus
from cell_harness import (
    CELL_YAML,
    FAST_MOTION,
    LOADED_COMMAND,
    LOADED_LIVENESS,
    Client,
    ProcessGroup,
    isolated_domain,
    stop_cleanly,
)
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from positioning_cell_interfaces.action import Calibrate

from positioning_cell import names
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import parameters as cp
from positioning_cell.motion.settings import CALIBRATION_FILE, machine_settings
from positioning_cell.ros.client import GoalClient
from positioning_cell.ros.messages import status_values
from positioning_cell.ros.qos import STREAM_QOS

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

#: The cell the calibrator drives (no monitor, no recorder needed).
CELL = ('leg_driver_node', 'pose_measurement_node', 'kinematics_node')
#: A short program (as test_run_cell's): 8 fit poses, 1 hold-out, 3 readings each.
GOAL = Calibrate.Goal(poses=8, hold_out=1, samples=3)
POSES = 9
MODE = 'compensation.mode'


class Cell:
    """The running cell, the test's client of it and the Calibrate action's client
    (:class:`GoalClient`: spun by the test's thread only)."""

    def __init__(self, client: Client, procs: ProcessGroup, out: Path) -> None:
        self.client, self.procs, self.out = client, procs, out
        self.goals = GoalClient(client, Calibrate, names.CALIBRATE_ACTION)
        self.action = self.goals.action

    def until(self, condition: Callable[[], Any], timeout: float, what: str) -> Any:
        """Spin the action's node until ``condition()`` is truthy (its value); a timeout
        names the processes that exited and shows what the calibrator logged."""
        try:
            return self.goals.until(condition, timeout, what)
        except TimeoutError as err:
            raise AssertionError(
                f'{err}; exited: {self.procs.dead()}\n'
                f'{self.procs.log(names.CALIBRATOR.executable)[-3000:]}') from None

    def send(self, feedback: list[Any], goal: Any = GOAL) -> Any:
        """Send ``goal``; its goal handle (accepted or not)."""
        return self.goals.send(goal, feedback.append)

    def result(self, handle: Any, timeout: float) -> Any:
        """The goal's result response (status and result)."""
        return self.goals.result(handle, timeout)

    def close(self) -> None:
        self.goals.close()


#: Motion ten times slower than FAST_MOTION, for the tests that stop a move while it runs:
#: at FAST_MOTION a move to the next pose lasts ~0.3 s, and on a loaded machine the stop (a
#: signal to the calibrator, its handler, the positioner's stop) reached the positioner after
#: the move had ended (seen in CI: no aborted_stop within 10 s).
SLOW_MOTION = {'linear_speed': 0.003, 'linear_acceleration': 0.015, 'angular_speed': 0.03,
               'angular_acceleration': 0.15}


@pytest.fixture
def cell(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Cell]:
    """The cell and the calibrator; the positioner's motion FAST_MOTION, or the fixture's
    parameter (indirect parametrization: SLOW_MOTION)."""
    out = tmp_path / 'calibration'
    motion = getattr(request, 'param', FAST_MOTION)
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as procs, \
            Client(domain, 'calibrator_test') as client:
        poses = client.collect(PoseStamped, names.ESTIMATED_POSE, STREAM_QOS)
        measured = client.collect(PoseWithCovarianceStamped, names.MEASURED_POSE, STREAM_QOS)
        for exe in CELL:
            # the test is of the action, not of the motion nor of liveness
            procs.start(exe, overrides={
                'kinematics_node': {names.NODE_POSITIONER: {'liveness': LOADED_LIVENESS,
                                                            'motion': motion}},
                'leg_driver_node': {names.NODE_DRIVER: {'command': LOADED_COMMAND}},
            }.get(exe))
        procs.start(names.CALIBRATOR.executable,
                    # no approach moves: half the moves per pose (the approach is run_cell's)
                    overrides={names.NODE_CALIBRATOR: {'out_dir': str(out),
                                                       'program': {'approach': 0.0}}})
        cell = Cell(client, procs, out)
        try:
            cell.until(lambda: poses and measured, 60.0, "the cell's poses")
            # the server known and this client known to it (GoalClient.ready's handshake):
            # server_is_ready alone let a goal's answer be lost (seen: no answer in 30 s)
            cell.goals.ready(60.0)
            yield cell
        finally:
            cell.close()
        stop_cleanly(procs)


def state(status: Any) -> str:
    return str(status_values(status).get('state', ''))


def test_a_goal_calibrates_the_cell_with_feedback_per_pose(cell: Cell) -> None:
    t0 = time.monotonic()
    feedback: list[Any] = []
    handle = cell.send(feedback)
    assert handle.accepted
    response = cell.result(handle, 120.0)
    result = response.result
    assert response.status == GoalStatus.STATUS_SUCCEEDED, result.reason
    assert result.success, result.reason
    cell.until(lambda: len(feedback) >= POSES, 5.0, 'the feedback of every pose')
    assert [(f.pose, f.poses) for f in feedback] == [(k, POSES) for k in range(1, POSES + 1)]
    assert [f.set_name for f in feedback] == ['fit'] * 8 + ['hold_out']
    # The uncompensated machine misses by tens to hundreds of µm.
    assert all(1e-6 < f.deviation < 2e-3 for f in feedback), [f.deviation for f in feedback]
    path = Path(result.calibration_file)
    assert path == (cell.out / 'calibration.yaml').resolve() and path.is_file()
    assert (cell.out / 'calibration_report.md').is_file()
    calfile.load(path, machine_settings(CELL_YAML).mechanism)  # parses, this mechanism's
    # the ROS port gave each pose's conditions: the sensor's temperature, and approaches from
    # both sides (the reversal terms are not left out for want of them)
    excluded = yaml.safe_load(path.read_text())['calibration']['excluded']
    assert 'no temperature recorded' not in excluded.values(), excluded
    assert 'no approach directions recorded' not in excluded.values(), excluded
    assert [n for n in cp.PARAMETER_NAMES[cp.REVERSAL] if n not in excluded], excluded
    assert 0.0 < result.fit_rms < 20e-6, result.fit_rms
    assert np.isfinite(result.hold_out_rms) and result.hold_out_rms > 0.0
    assert 0 < result.identified <= cp.COUNT
    client = cell.client
    assert client.get_parameter(names.NODE_POSITIONER, CALIBRATION_FILE) == str(path)
    assert client.get_parameter(names.NODE_POSITIONER, MODE) == 'measured'  # put back
    print(f'calibrated over the action in {time.monotonic() - t0:.1f} s: fit RMS '
          f'{result.fit_rms * 1e6:.2f} um, hold-out RMS {result.hold_out_rms * 1e6:.2f} um, '
          f'{result.identified} parameters; {result.reason}')


def _moving_to_the_second_pose(cell: Cell) -> tuple[list[Any], list[Any], Any, Any]:
    """A goal sent, its first pose measured, the positioner moving to the next one: the
    positioner's statuses, the feedback so far, the goal handle and its result future."""
    statuses = cell.client.statuses(names.STATUS_POSITIONER)
    feedback: list[Any] = []
    handle = cell.send(feedback)
    assert handle.accepted
    result = handle.get_result_async()
    cell.until(lambda: feedback or result.done(), 90.0, 'the feedback of the first pose')
    assert feedback, f'the goal ended first: {result.result().result.reason}'
    cell.until(lambda: statuses and state(statuses[-1]) == 'moving', 10.0,
               'the move to the next pose')
    return statuses, feedback, handle, result


@pytest.mark.parametrize('cell', [SLOW_MOTION], indirect=True)
def test_cancel_stops_the_move_and_writes_nothing(cell: Cell) -> None:
    client = cell.client
    statuses, feedback, handle, result = _moving_to_the_second_pose(cell)
    assert not cell.send([]).accepted  # one calibration at a time
    # Cancel while the positioner moves to the next pose: the move ends aborted_stop.
    seen = len(statuses)
    t0 = time.monotonic()
    cancel = handle.cancel_goal_async()
    cell.until(cancel.done, 10.0, 'the answer to the cancel')
    cell.until(result.done, 30.0, 'the result of the canceled goal')
    stopped_in = time.monotonic() - t0
    response = result.result()
    assert response.status == GoalStatus.STATUS_CANCELED, response.result.reason
    assert not response.result.success and 'nothing written' in response.result.reason
    assert response.result.calibration_file == ''
    assert len(feedback) < POSES
    # the positioner's own status comes on /diagnostics, in its own time: wait for it
    cell.until(lambda: 'aborted_stop' in [status_values(s).get('code')
                                          for s in statuses[seen:]], 10.0,
               "the positioner's aborted_stop status")
    assert state(statuses[-1]) != 'moving'
    assert not (cell.out / 'calibration.yaml').exists()
    assert client.get_parameter(names.NODE_POSITIONER, CALIBRATION_FILE) == ''
    assert client.get_parameter(names.NODE_POSITIONER, MODE) == 'measured'  # put back
    # The node serves the next goal: one out of range is refused with the reason ...
    bad = cell.result(cell.send([], Calibrate.Goal(poses=5)), 10.0)
    assert bad.status == GoalStatus.STATUS_ABORTED and not bad.result.success
    assert bad.result.reason.startswith('invalid goal: poses = 5'), bad.result.reason
    # ... another one runs.
    again = cell.send([])
    assert again.accepted
    again.cancel_goal_async()
    assert cell.result(again, 60.0).status == GoalStatus.STATUS_CANCELED
    print(f'canceled after {len(feedback)} poses; result {stopped_in:.2f} s after the cancel')


@pytest.mark.parametrize('cell', [SLOW_MOTION], indirect=True)
def test_a_shutdown_mid_calibration_stops_the_move_and_puts_the_mode_back_at_once(
        cell: Cell) -> None:
    """SIGINT to the calibrator while the positioner moves to a pose: the goal's stop event
    stops the drives at once, the mode is put back, nothing written, and the node exits
    well before its longest wait (CLOSE_WAIT_S) would have run out."""
    from positioning_cell.nodes.calibrator_node import CLOSE_WAIT_S
    client = cell.client
    statuses, _, _, _ = _moving_to_the_second_pose(cell)
    seen = len(statuses)
    t0 = time.monotonic()
    exe = names.CALIBRATOR.executable
    assert cell.procs.stop(exe, grace=2 * CLOSE_WAIT_S) == {exe: 0}, cell.procs.log(exe)[-2000:]
    closed_in = time.monotonic() - t0
    assert closed_in < CLOSE_WAIT_S, closed_in
    # the positioner's own status comes on /diagnostics, in its own time: wait for it
    cell.until(lambda: 'aborted_stop' in [status_values(s).get('code')
                                          for s in statuses[seen:]], 10.0,
               "the positioner's aborted_stop status")
    assert client.get_parameter(names.NODE_POSITIONER, MODE) == 'measured'  # put back
    assert client.get_parameter(names.NODE_POSITIONER, CALIBRATION_FILE) == ''
    assert not (cell.out / 'calibration.yaml').exists()
    assert 'calibration stopped: drives stopped, nothing written' in cell.procs.log(exe)
    print(f'the calibrator exited {closed_in:.2f} s after SIGINT, mid-calibration')
