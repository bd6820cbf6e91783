"""The fault matrix: each fault injected into the running cell, the reaction expected of it
(result code, words of the reason, time bound), and a trial that injects it and measures what
happened, checking from the simulator's true joint states (/sim/legs/true_joint_states) that
the drives stopped and that no axis went beyond its limits.

The README's "Fault matrix" table is :data:`FAULTS` (:func:`markdown_table`);
``test/test_faults.py`` runs one trial of each, ``benchmarks/faults.py`` 20 and prints the
reaction times. A trial runs against a :class:`FaultCell`: the four nodes and the recorder as
processes on a private domain, homed. Reaction time: from the injection (just before the
parameter call, the kill, the publish) to the receipt of the positioner's status carrying the
result code (the driver's answer for a trajectory sent to it directly; the driver's status
for a silent commander; the positioner's input status for a second publisher; the last reply
for a flood of calls); for motion nobody commanded, from the moment the true position passes
the standstill tolerance. The truth is read here only to judge.

``python -m positioning_cell.tools.fault_matrix [fault ...]`` runs one trial of each named
fault (all without names) on a fresh cell and prints the results.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from positioning_cell_interfaces.msg import MoveCommand
from positioning_cell_interfaces.srv import CheckPose, MoveToPose
from rclpy.duration import Duration
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.motion.settings import LivenessSettings, PositionerSettings
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.parameters import RULE, parse
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.messages import duration, pose_arrays, pose_stamped, status_values
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.ros.qos import COMMAND_QOS, DIAGNOSTICS_QOS, STREAM_QOS
from positioning_cell.sim.guard import Refusal

#: The trial moves run along base z between home - SPAN and home + SPAN (about 1.6 s each at
#: the shipped 10 mm/s), so a fault lands mid-move.
SPAN = 0.007
#: At rest: every true joint speed below these (m/s, rad/s) for REST_WINDOW s.
REST_SPEED = (1e-6, 1e-5)
REST_WINDOW = 0.2
#: After the reaction, the drives must be at rest within this (the controlled deceleration).
STOP_WITHIN = 1.0
#: Calls per service in the flood, and the bound on answering all of them.
FLOOD_CALLS = 100
#: The liveness rules at the lax end of their ranges (the parameters' upper limits).
LAX_LIVENESS = {f.name: f.metadata[RULE].high for f in fields(LivenessSettings)
                if f.name in ('joint_silence', 'answer_timeout', 'freeze_window',
                              'tracker_silence', 'scatter_limit')}
DRIVER = next(n for n in names.CELL_NODES if n.name == names.NODE_DRIVER)
TRACKER = next(n for n in names.CELL_NODES if n.name == names.NODE_MEASUREMENT)
POSITIONER = next(n for n in names.CELL_NODES if n.name == names.NODE_POSITIONER)
#: The client's node: what the cell sees as the sender of a foreign message.
CLIENT_NODE = 'fault_matrix'
#: How far ahead the foreign trajectory is stamped (the issue's probe: run 4 s later).
AHEAD_S = 4.0
#: A spoofed input: how far it is off, how many messages at what period.
SPOOF_OFFSET = 1.7e-3
SPOOF_MESSAGES, SPOOF_PERIOD = 50, 0.01
#: The motion nobody commands: [axis index, distance m] (fault.uncommanded_motion).
UNCOMMANDED = (0.0, 2e-3)


@dataclass
class Trial:
    """What one trial of a fault gave: the result ``code`` and ``reason`` the cell reported,
    ``reaction_s`` (injection → that report), ``stopped_s`` (injection → all axes at rest; None
    when not measured), ``within_limits`` (every true joint position inside the stroke and
    angle range), ``problems`` (each way the reaction differed from the expected one)."""

    fault: str
    code: str = ''
    reason: str = ''
    reaction_s: float = math.nan
    stopped_s: float | None = None
    within_limits: bool = True
    problems: list[str] = field(default_factory=list)
    inject_s: float = 0.0

    @property
    def ok(self) -> bool:
        """The reaction was the expected one."""
        return not self.problems


Action = Callable[['FaultCell'], None]


def _nothing(cell: FaultCell) -> None:
    return None


@dataclass(frozen=True)
class Fault:
    """One row of the matrix: ``injection`` (done by ``inject``: mid-move, or just before the
    move when not ``mid_move``; ``prepare`` before the move) in compensation ``mode``;
    expected: ``reaction``, a result code among ``codes`` with ``reason`` in its reason within
    ``bound_s`` s, the drives at rest after it (``stops``), and what ``after`` checks next.
    ``restore`` puts the cell back;
    ``kind`` picks the trial: ``move`` (a move with the fault), ``trajectory`` (a trajectory
    sent to the driver directly by another node), ``flood`` (concurrent calls to every
    service), ``standstill`` (motion while nothing is commanded), ``spoof`` (a second
    publisher on an input of the positioner: ``topic``), ``commander`` (the positioner
    killed mid-move)."""

    name: str
    injection: str
    reaction: str
    codes: tuple[str, ...]
    reason: str
    bound_s: float
    inject: Action = _nothing
    prepare: Action = _nothing
    mode: str = 'none'
    mid_move: bool = True
    stops: bool = True
    after: Callable[[FaultCell, Trial], None] = lambda cell, trial: None
    restore: Action = _nothing
    kind: str = 'move'
    topic: str = ''


class FaultCell:
    """The cell under test: leg driver, tracker simulator, positioner, monitor and recorder
    as processes on a private ROS domain (``log_dir``: their logs and the bag), and a client
    watching the positioner's statuses, the drives' answers, the true joint states and poses
    and the tracker, each with its receipt time (time.monotonic)."""

    def __init__(self, log_dir: Path, config: Path | None = None) -> None:
        self.log_dir = log_dir
        self.config = config or config_path('cell.yaml')
        params = load_parameter_file(self.config)
        positioner = parse(PositionerSettings, node_parameters(params, names.NODE_POSITIONER))
        self.mech = positioner.mechanism
        self.tolerance = positioner.goal_tolerance.position
        self.liveness_settings = {name: getattr(positioner.liveness, name)
                                  for name in LAX_LIVENESS}
        self._stack = contextlib.ExitStack()
        self.domain = self._stack.enter_context(free_domain())
        self.procs = self._stack.enter_context(
            Processes(cell_environment(self.domain), log_dir))
        self.client = self._stack.enter_context(CellClient(self.domain, CLIENT_NODE))
        node = self.client.node
        self.positioner: list[tuple[float, DiagnosticStatus]] = []
        self.inputs: list[tuple[float, DiagnosticStatus]] = []
        self.driver: list[tuple[float, DiagnosticStatus]] = []
        self.standstill_tolerance = positioner.standstill.joint_tolerance
        self.answers: list[tuple[float, DiagnosticStatus]] = []
        self.truth: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.true_pose: list[tuple[float, np.ndarray]] = []
        self.tracker_sigma = math.nan
        node.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS)
        node.create_subscription(DiagnosticStatus, names.TRAJECTORY_STATUS,
                                 lambda s: self.answers.append((time.monotonic(), s)),
                                 STREAM_QOS)
        node.create_subscription(JointState, names.TRUE_JOINT_STATES, self._on_truth,
                                 STREAM_QOS)
        node.create_subscription(PoseStamped, names.TRUE_POSE, self._on_true_pose, STREAM_QOS)
        node.create_subscription(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                 self._on_measured, STREAM_QOS)
        node.create_subscription(PoseStamped, names.ESTIMATED_POSE, self._on_estimate,
                                 STREAM_QOS)
        self.estimates: list[tuple[float, np.ndarray]] = []
        overrides = log_dir / 'fault_matrix.yaml'
        overrides.write_text(f'{names.NODE_RECORDER}:\n  ros__parameters:\n'
                             f'    output: {log_dir / "bag"}\n')
        self._params = [self.config, overrides]
        self.estimate: np.ndarray | None = None
        self._lock = threading.Lock()

    # -- what the client sees -------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        with self._lock:
            for status in msg.status:
                into = {names.STATUS_POSITIONER: self.positioner,
                        names.STATUS_POSITIONER_INPUTS: self.inputs,
                        names.STATUS_DRIVER: self.driver}.get(status.name)
                if into is not None:
                    into.append((now, status))
                    del into[:-5000]

    def _on_truth(self, msg: JointState) -> None:
        with self._lock:
            self.truth.append((time.monotonic(), np.array(msg.position),
                               np.array(msg.velocity)))
            del self.truth[:-20_000]

    def _on_true_pose(self, msg: PoseStamped) -> None:
        with self._lock:
            self.true_pose.append((time.monotonic(), pose_arrays(msg.pose)[0]))
            del self.true_pose[:-1000]

    def _on_estimate(self, msg: PoseStamped) -> None:
        self.estimate = pose_arrays(msg.pose)[0]
        with self._lock:
            self.estimates.append((time.monotonic(), self.estimate))
            del self.estimates[:-5000]

    def _on_measured(self, msg: PoseWithCovarianceStamped) -> None:
        self.tracker_sigma = float(np.sqrt(np.max(np.diag(
            np.reshape(msg.pose.covariance, (6, 6)))[:3])))


    def result_after(self, since: float) -> tuple[float, str, str] | None:
        """The first positioner status received after ``since`` that carries a result code:
        (receipt time, code, message)."""
        with self._lock:
            statuses = list(self.positioner)
        for t, status in statuses:
            code = status_values(status).get('code', '')
            if t > since and code:
                return t, code, status.message
        return None

    def status_after(self, statuses: list[tuple[float, DiagnosticStatus]], since: float,
                     words: str) -> tuple[float, DiagnosticStatus] | None:
        """The first of ``statuses`` received after ``since`` whose message has ``words``."""
        with self._lock:
            return next(((t, s) for t, s in statuses if t > since and words in s.message),
                        None)

    def answer_after(self, since: float) -> tuple[float, DiagnosticStatus] | None:
        """The first answer of the drives received after ``since``."""
        with self._lock:
            return next(((t, s) for t, s in self.answers if t > since), None)

    def truth_after(self, since: float) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """True joint states (receipt time, positions, velocities) received after ``since``."""
        with self._lock:
            return [x for x in self.truth if x[0] > since]

    # -- processes ------------------------------------------------------------------------------
    def start(self) -> None:
        """Start every process, wait until each answers, home."""
        for node in (*names.CELL_NODES, names.RECORDER):
            self.procs.start(node.executable, params=self._params, label=node.executable)
        for node in (*names.CELL_NODES, names.RECORDER):
            wait_until(partial(self.client.spinning, node.name), 90.0, f'{node.name} to answer')
        self.ready('none')

    def kill(self, node: names.CellNode) -> None:
        """SIGKILL ``node``'s process (no clean-up: a crash)."""
        os.killpg(self.procs.procs[node.executable].pid, signal.SIGKILL)

    def restart(self, node: names.CellNode) -> None:
        """Start ``node`` again after it was killed and wait until it answers."""
        self.procs.stop(node.executable, signal.SIGKILL, grace=5.0)
        self.procs.start(node.executable, params=self._params, label=node.executable)
        self.client.forget(node.name)
        wait_until(lambda: self.client.spinning(node.name), 90.0, f'{node.name} to answer')

    def close(self) -> dict[str, int]:
        """Stop every process (SIGINT); their exit codes."""
        try:
            return self.procs.stop()
        finally:
            self._stack.close()

    def __enter__(self) -> FaultCell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- commands -------------------------------------------------------------------------------
    def set(self, node: str, name: str, value: Any) -> None:
        """Set a parameter; RuntimeError if the node refuses it."""
        result = self.client.set_parameter(node, name, value)
        if not result.successful:
            raise RuntimeError(f'{node} refused {name} = {value!r}: {result.reason}')

    def enable(self, on: bool) -> None:
        """Switch the drives on or off (on also clears a drive fault)."""
        response = self.client.call(SetBool, names.DRIVER_ENABLE, SetBool.Request(data=on))
        if not response.success:
            raise RuntimeError(f'{names.DRIVER_ENABLE} {on}: {response.message}')

    def liveness(self, on: bool) -> None:
        """The positioner's liveness rules as configured (``on``), or as lax as their
        parameters allow (the baseline of benchmarks/faults.py: only the timeouts remain)."""
        for name, value in self.liveness_settings.items():
            self.set(names.NODE_POSITIONER, f'liveness.{name}',
                     value if on else LAX_LIVENESS.get(name, value))

    def ready(self, mode: str) -> None:
        """No fault injected, drives enabled, compensation ``mode``, referenced and homed when
        not, and the positioner accepting both trial goals."""
        cleared: list[tuple[str, str, Any]] = [
            (names.NODE_DRIVER, 'fault.encoder_dropout', ''),
            (names.NODE_DRIVER, 'fault.stuck_axis', ''),
            (names.NODE_DRIVER, 'fault.encoder_dropout_mode', 'freeze'),
            (names.NODE_DRIVER, 'fault.noise_burst', [1.0, 0.0]),
            (names.NODE_DRIVER, 'fault.uncommanded_motion', [0.0, 0.0]),
            (names.NODE_MEASUREMENT, 'fault.occlusion_probability', 0.0),
            (names.NODE_MEASUREMENT, 'fault.outlier_probability', 0.0)]
        for node, name, value in cleared:
            self.set(node, name, value)
        self.enable(True)
        self.set(names.NODE_POSITIONER, 'compensation.mode', mode)
        for k in (0, 1):
            wait_until(partial(self._accepts, *self.goal(k)), 60.0,
                       'the positioner to accept the trial goals')

    def _accepts(self, position: np.ndarray, quaternion: np.ndarray) -> bool:
        """check_pose accepts the goal; refused as not referenced (the drives were restarted
        or never homed): home first."""
        asked = time.monotonic()
        if self.client.plan(names.CHECK_POSE, position, quaternion, timeout=10.0):
            return True
        refusal = wait_until(lambda: self.result_after(asked), 10.0, 'the refusal')
        if refusal[1] == ResultCode.REFUSED_NOT_REFERENCED.value:
            done, message = self.client.home()
            if not done:
                raise RuntimeError(f'homing failed: {message}')
        return False

    def goal(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Trial goal ``k`` (0: below home, 1: above): position m, quaternion, base frame."""
        offset = np.array([0.0, 0.0, SPAN if k else -SPAN])
        return self.mech.home_position + offset, np.array(self.mech.home_quaternion)

    def move(self) -> tuple[float, threading.Thread, tuple[np.ndarray, np.ndarray]]:
        """Start a move to the trial goal farther from where the positioner estimates the
        platform (a goal it is already at succeeds without moving) in a thread: (start time,
        thread, goal)."""
        here = self.estimate if self.estimate is not None else self.mech.home_position
        goal = max((self.goal(k) for k in (0, 1)),
                   key=lambda g: float(np.linalg.norm(g[0] - here)))
        def run() -> None:
            with contextlib.suppress(TimeoutError):  # a killed positioner never answers
                self.client.plan(names.MOVE_TO_POSE, *goal, timeout=120.0)

        thread = threading.Thread(target=run, daemon=True)
        started = time.monotonic()
        thread.start()
        return started, thread, goal

    def moving(self, since: float) -> bool:
        """A true joint state received after ``since`` shows an axis moving."""
        return any(_moving(v) for _, _, v in self.truth_after(since)[-20:])

    def rest_time(self, since: float) -> float | None:
        """Receipt time from which every axis stayed at rest for REST_WINDOW s (true joint
        states received after ``since``); None if they did not (yet)."""
        start = None
        for t, _, v in self.truth_after(since):
            if _moving(v):
                start = None
            elif start is None:
                start = t
            if start is not None and t - start >= REST_WINDOW:
                return start
        return None

    def within_limits(self, since: float) -> bool:
        """Every true joint position received after ``since`` inside the stroke and the
        second-U-angle range (1 nm / 1 nrad of slack)."""
        m, eps = self.mech, 1e-9
        lo = np.array([m.length_min] * 3 + [m.theta_min] * 3) - eps
        hi = np.array([m.length_max] * 3 + [m.theta_max] * 3) + eps
        return all(bool(np.all((p >= lo) & (p <= hi))) for _, p, _ in self.truth_after(since))


def _moving(velocity: np.ndarray) -> bool:
    return bool(np.any(np.abs(velocity[:3]) > REST_SPEED[0])
                or np.any(np.abs(velocity[3:]) > REST_SPEED[1]))


# -- trials -----------------------------------------------------------------------------------
class _LandedLateError(Exception):
    """The injection returned only after the motion had ended: the move rightly succeeded,
    and the trial did not test the fault mid-move (on a loaded machine a parameter call can
    take longer than the rest of the move)."""


#: Attempts of a trial whose fault landed after the motion.
ATTEMPTS = 3


def run_trial(cell: FaultCell, fault: Fault) -> Trial:
    """One trial of ``fault`` on ``cell`` (ready first, restored after); a trial whose fault
    landed after the motion is run again, up to ATTEMPTS times."""
    for attempt in range(1, ATTEMPTS + 1):
        trial = Trial(fault.name)
        cell.ready(fault.mode)
        began = time.monotonic()
        try:
            {'move': _move_trial, 'trajectory': _trajectory_trial, 'flood': _flood_trial,
             'standstill': _standstill_trial, 'spoof': _spoof_trial,
             'commander': _commander_trial}[fault.kind](cell, fault, trial)
            fault.after(cell, trial)
        except _LandedLateError as late:
            if attempt == ATTEMPTS:
                trial.problems.append(f'{late} in all {ATTEMPTS} attempts')
            else:
                continue
        except TimeoutError as err:
            trial.problems.append(str(err))
        finally:
            trial.within_limits = cell.within_limits(began)
            if not trial.within_limits:
                trial.problems.append('an axis went beyond its limit')
            fault.restore(cell)
        return trial
    raise AssertionError('unreachable')


def _judge(trial: Trial, fault: Fault) -> None:
    if trial.code not in fault.codes:
        trial.problems.append(f'result {trial.code!r}, expected {" or ".join(fault.codes)}')
    if fault.reason not in trial.reason:
        trial.problems.append(f'reason {trial.reason!r} lacks {fault.reason!r}')
    if not trial.reaction_s <= fault.bound_s:
        trial.problems.append(f'reaction {trial.reaction_s:.3f} s > {fault.bound_s} s')


def _move_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """A move with the fault injected (mid-move, or just before it), the result, the axes at
    rest after a failure, the true pose within tolerance after a success in ``measured``."""
    fault.prepare(cell)
    if not fault.mid_move:
        injected = time.monotonic()
        fault.inject(cell)
    started, thread, goal = cell.move()
    if fault.mid_move:
        wait_until(lambda: cell.moving(started), 30.0, 'the axes to move')
        injected = time.monotonic()
        fault.inject(cell)
    trial.inject_s = time.monotonic() - injected
    injection_done = injected + trial.inject_s
    received, trial.code, trial.reason = wait_until(
        lambda: cell.result_after(started), fault.bound_s + 60.0, 'the result of the move')
    thread.join(timeout=60.0)
    trial.reaction_s = received - injected
    success = trial.code == ResultCode.SUCCESS.value
    if (fault.mid_move and success and ResultCode.SUCCESS.value not in fault.codes
            and not any(_moving(v) for _, _, v in cell.truth_after(injection_done - 0.02)[:3])):
        raise _LandedLateError(f'the injection took {trial.inject_s:.2f} s and ended after the '
                          'motion')
    _judge(trial, fault)
    if success and fault.mode == 'measured':
        _judge_success(cell, trial, goal[0], received)
    elif fault.stops:
        _judge_stop(cell, trial, injected, received)


def _judge_stop(cell: FaultCell, trial: Trial, injected: float, received: float) -> None:
    """The axes at rest within STOP_WITHIN s of the reaction; a killed driver takes the
    simulated drives with it (no true joint states after it)."""
    if DRIVER.executable not in cell.procs.dead():
        rest = wait_until(lambda: cell.rest_time(injected) or
                          (time.monotonic() > received + STOP_WITHIN + 1.0 and -1.0),
                          STOP_WITHIN + 5.0, 'the axes to come to rest')
        trial.stopped_s = None if rest < 0 else max(rest - injected, 0.0)
        if rest < 0 or rest > received + STOP_WITHIN:
            trial.problems.append(f'drives not at rest within {STOP_WITHIN} s of the reaction')
        return
    after = cell.truth_after(injected + 0.1)
    trial.stopped_s = 0.0
    if after:
        trial.problems.append('true joint states after the driver was killed')


def _judge_success(cell: FaultCell, trial: Trial, goal: np.ndarray, received: float) -> None:
    """A success in ``measured`` mode (settled within tolerance as the tracker sees it): the
    true position within the goal tolerance plus three of the tracker's stated sigmas. (In
    ``none`` and ``model`` the tolerance holds for the encoders' estimate, and the truth differs
    from it by the uncompensated clearance.)"""
    wait_until(lambda: any(t > received for t, _ in cell.true_pose), 10.0, 'a true pose')
    true_position = next(p for t, p in cell.true_pose if t > received)
    error = float(np.linalg.norm(true_position - goal))
    limit = cell.tolerance + 3.0 * cell.tracker_sigma
    if not error <= limit:
        trial.problems.append(f'success, but the true position is {error * 1e6:.1f} um from '
                              f'the goal (tolerance + 3 sigma: {limit * 1e6:.1f} um)')


def _trajectory_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """A trajectory from another node (this client) beyond the axis limits at a legal speed,
    stamped AHEAD_S s ahead: refused as foreign, the driver names the publisher on
    /diagnostics, and the axes hold, also after the stamp's time has come."""
    wait_until(lambda: cell.truth_after(time.monotonic() - 0.5), 10.0, 'true joint states')
    here = cell.truth_after(-math.inf)[-1][1]
    beyond = here.copy()
    beyond[[0, 1, 3]] = 0.240, 0.150, 1.2  # leg 1, leg 2 lengths (m), theta 1 (rad)
    node = cell.client.node
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    msg.header.stamp = (node.get_clock().now() + Duration(seconds=AHEAD_S)).to_msg()
    msg.points = [JointTrajectoryPoint(positions=here.tolist(), velocities=[0.0] * 6,
                                       time_from_start=duration(0.0)),
                  JointTrajectoryPoint(positions=beyond.tolist(), velocities=[0.0] * 6,
                                       time_from_start=duration(20.0))]
    created = time.monotonic()
    publisher = node.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY, COMMAND_QOS)
    try:
        # The driver reports the new publisher from the graph before it has sent anything
        # (and once it has, both sides have matched: the reaction below is the driver's).
        words = f'foreign publisher on {names.JOINT_TRAJECTORY}: /{CLIENT_NODE}'
        wait_until(lambda: cell.status_after(cell.driver, created, words), 10.0,
                   f'the driver to report {words!r}')
        injected = time.monotonic()
        fault.inject(cell)
        publisher.publish(msg)
        received, answer = wait_until(lambda: cell.answer_after(injected), 10.0, 'the answer')
        values = status_values(answer)
        trial.code = values.get('code', '') if values.get('accepted') == 'false' else 'accepted'
        trial.reason, trial.reaction_s = answer.message, received - injected
        _judge(trial, fault)
        wait_until(lambda: cell.truth_after(received + AHEAD_S + 0.5), AHEAD_S + 10.0,
                   'true joint states after the stamp')
    finally:
        node.destroy_publisher(publisher)
    held = np.array([p for _, p, _ in cell.truth_after(received)])
    if np.ptp(held, axis=0).max() > 1e-7:
        trial.problems.append(f'the axes moved {np.ptp(held, axis=0).max():.2e} after the '
                              'refusal')
    trial.stopped_s = 0.0


def _standstill_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """Motion nobody commanded while the cell stands still: the positioner reports it
    (uncommanded_motion) within the bound of the true position leaving the standstill
    tolerance, the drives stop short of the motion's end, and the next move succeeds,
    planned from where the encoders are."""
    wait_until(lambda: cell.rest_time(time.monotonic() - 1.0), 10.0, 'the axes at rest')
    rest = cell.truth_after(time.monotonic() - 0.2)[-1][1]
    injected = time.monotonic()
    fault.inject(cell)
    trial.inject_s = time.monotonic() - injected
    received, trial.code, trial.reason = wait_until(
        lambda: cell.result_after(injected), fault.bound_s + 10.0, 'the positioner to react')
    beyond = next((t for t, p, _ in cell.truth_after(injected)
                   if np.any(np.abs(p - rest) > cell.standstill_tolerance)), None)
    if beyond is None:
        trial.problems.append('reported before the true motion passed the tolerance')
        beyond = received
    trial.reaction_s = received - beyond
    _judge(trial, fault)
    _judge_stop(cell, trial, beyond, received)
    moved = max(float(np.max(np.abs(p - rest))) for _, p, _ in cell.truth_after(injected))
    if moved > 0.9 * abs(UNCOMMANDED[1]):
        trial.problems.append(f'the axis moved {moved * 1e3:.3f} mm: the drives were not '
                              'stopped short of the motion')
    started, thread, _ = cell.move()
    thread.join(timeout=120.0)
    result = cell.result_after(started)
    if result is None or result[1] != ResultCode.SUCCESS.value:
        trial.problems.append(f'the next move gave {result}')


def _spoof_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """A second publisher (this client) on an input of the positioner, SPOOF_MESSAGES
    messages SPOOF_OFFSET off the truth while the cell stands still: the positioner names it
    within the bound, and neither its estimate moves nor a fault follows."""
    wait_until(lambda: cell.rest_time(time.monotonic() - 1.0), 10.0, 'the axes at rest')
    node = cell.client.node
    kind = JointState if fault.topic == names.JOINT_STATES else PoseWithCovarianceStamped
    publisher = node.create_publisher(kind, fault.topic, STREAM_QOS)
    before = cell.estimate
    try:
        wait_until(lambda: publisher.get_subscription_count() > 0, 10.0, 'the cell to match')
        msg = _spoof_message(cell, kind)
        injected = time.monotonic()
        for _ in range(SPOOF_MESSAGES):  # paced like a sensor
            publisher.publish(msg)
            time.sleep(SPOOF_PERIOD)
        words = f'second publisher on {fault.topic}: /{CLIENT_NODE}'
        received, status = wait_until(lambda: cell.status_after(cell.inputs, injected, words),
                                      fault.bound_s + 10.0, f'the positioner to report {words}')
    finally:
        node.destroy_publisher(publisher)
    trial.code, trial.reason = 'second_publisher', status.message
    trial.reaction_s = received - injected
    _judge(trial, fault)
    with cell._lock:
        estimates = [p for t, p in cell.estimates if t > injected]
    if before is not None and estimates:
        jump = max(float(np.linalg.norm(p - before)) for p in estimates)
        if jump > 10e-6:
            trial.problems.append(f'the estimate moved {jump * 1e6:.1f} um')
    late = cell.result_after(injected)
    if late is not None:
        trial.problems.append(f'a result {late[1]!r} followed: {late[2]}')
    trial.stopped_s = 0.0


def _spoof_message(cell: FaultCell, kind: Any) -> Any:
    """A reading SPOOF_OFFSET off the truth: encoders (leg 1 longer) or tracker (z)."""
    stamp = cell.client.node.get_clock().now().to_msg()
    if kind is JointState:
        position = cell.truth_after(-math.inf)[-1][1].copy()
        position[0] += SPOOF_OFFSET
        return JointState(header=Header(stamp=stamp), name=list(JOINT_NAMES),
                          position=position.tolist(), velocity=[0.0] * 6)
    with cell._lock:
        true_position = cell.true_pose[-1][1]
    msg = PoseWithCovarianceStamped(header=Header(stamp=stamp, frame_id=names.BASE_FRAME))
    msg.pose.pose = pose_stamped(true_position + [0.0, 0.0, SPOOF_OFFSET],
                                 cell.mech.home_quaternion, stamp).pose
    msg.pose.covariance = (np.eye(6) * 1e-12).ravel().tolist()
    return msg


def _commander_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """The positioner killed mid-move: the drives stop under control when its heartbeat falls
    silent (the driver's status says so) instead of finishing the trajectory unsupervised."""
    started, _, _ = cell.move()
    wait_until(lambda: cell.moving(started), 30.0, 'the axes to move')
    injected = time.monotonic()
    fault.inject(cell)
    received, status = wait_until(lambda: cell.status_after(cell.driver, injected, 'silent'),
                                  fault.bound_s + 10.0, 'the driver to stop the axes')
    trial.code, trial.reason = 'commander_silent', status.message
    trial.reaction_s = received - injected
    _judge(trial, fault)
    _judge_stop(cell, trial, injected, received)


def _flood_trial(cell: FaultCell, fault: Fault, trial: Trial) -> None:
    """FLOOD_CALLS concurrent calls to every service of the cell, all at once: every one
    answered (success, busy or a refusal) within the bound."""
    goal = MoveCommand(pose=pose_stamped(*cell.goal(0),
                                         cell.client.node.get_clock().now().to_msg()))
    calls: list[tuple[Any, str, Any]] = [
        (MoveToPose, names.MOVE_TO_POSE, MoveToPose.Request(command=goal)),
        (CheckPose, names.CHECK_POSE, CheckPose.Request(command=goal)),
        (Trigger, names.HOME, Trigger.Request()), (Trigger, names.STOP, Trigger.Request()),
        (SetBool, names.DRIVER_ENABLE, SetBool.Request(data=True)),
        (Trigger, names.DRIVER_REFERENCE, Trigger.Request()),
        (Trigger, names.MONITOR_REPORT, Trigger.Request()),
        (Trigger, names.MONITOR_RESET, Trigger.Request()),
        (Trigger, names.RECORDER_PAUSE, Trigger.Request()),
        (Trigger, names.RECORDER_RESUME, Trigger.Request())]
    for srv, name, _ in calls:
        cell.client.service(srv, name, wait=10.0)
    injected = time.monotonic()
    futures = [f for srv, name, request in calls
               for f in cell.client.call_many(srv, name, [request] * FLOOD_CALLS)]
    with contextlib.suppress(TimeoutError):
        wait_until(lambda: all(f.done() for f in futures), fault.bound_s, 'every answer')
    answered = sum(f.done() and f.result() is not None for f in futures)
    trial.reaction_s = time.monotonic() - injected
    trial.code = f'{answered}/{len(futures)} answered'
    per_service = [futures[i * FLOOD_CALLS:(i + 1) * FLOOD_CALLS] for i in range(len(calls))]
    trial.reason = ', '.join(f'{name} {sum(f.done() for f in mine)}'
                             for (_, name, _), mine in zip(calls, per_service, strict=True))
    if answered < len(futures):
        trial.problems.append(f'{len(futures) - answered} of {len(futures)} calls unanswered '
                              f'after {fault.bound_s} s')
    if not trial.reaction_s <= fault.bound_s:
        trial.problems.append(f'reaction {trial.reaction_s:.3f} s > {fault.bound_s} s')
    cell.client.trigger(names.RECORDER_RESUME)


# -- the matrix -------------------------------------------------------------------------------
def _set(node: str, name: str, value: Any) -> Action:
    return lambda cell: cell.set(node, name, value)


def _restart(node: names.CellNode) -> Action:
    def restore(cell: FaultCell) -> None:
        cell.restart(node)
        cell.ready('none')
    return restore


def _first_move_after_restart(cell: FaultCell, trial: Trial) -> None:
    """The positioner started again beside the running driver: its very first move succeeds
    (it waits for the inputs it has not seen yet and plans from where the encoders are)."""
    cell.restart(POSITIONER)
    started, thread, _ = cell.move()
    thread.join(timeout=120.0)
    result = cell.result_after(started)
    if result is None or result[1] != ResultCode.SUCCESS.value:
        trial.problems.append(f'the first move of the restarted positioner gave {result}')


def _running(node: names.CellNode) -> Action:
    def restore(cell: FaultCell) -> None:
        if node.executable in cell.procs.dead():
            cell.restart(node)
    return restore


def _refused_while_driver_gone(cell: FaultCell, trial: Trial) -> None:
    """After the driver was killed: a new move is refused as silent."""
    asked = time.monotonic()
    cell.client.plan(names.MOVE_TO_POSE, *cell.goal(0), timeout=30.0)
    _, code, message = wait_until(lambda: cell.result_after(asked), 30.0, 'the refusal')
    if code != ResultCode.REFUSED_DRIVER_SILENT.value:
        trial.problems.append(f'a move while the driver is gone gave {code!r}: {message}')


R = ResultCode
FAULTS: tuple[Fault, ...] = (
    Fault('foreign trajectory',
          'a JointTrajectory from another node (the matrix\'s client) on /legs/joint_trajectory, '
          f'stamped {AHEAD_S:g} s ahead, taking leg1 to 240 mm, leg2 to 150 mm, theta1 to '
          '1.2 rad',
          'the driver refuses it, naming the sender; it reports the foreign publisher on '
          '/diagnostics; the axes hold, also when the stamp\'s time has come',
          (Refusal.FOREIGN_SENDER.value,), f'sent by /{CLIENT_NODE}', 0.1, kind='trajectory'),
    Fault('encoder NaN', 'fault.encoder_dropout leg2_length, mode missing, mid-move',
          'the move aborts: the reading is not a number (or the driver faults: encoder lost), '
          'naming the axis',
          (R.ABORTED_FAULT.value, R.ABORTED_ENCODER.value), 'leg2_length', 0.5,
          _set(names.NODE_DRIVER, 'fault.encoder_dropout', 'leg2_length'),
          prepare=_set(names.NODE_DRIVER, 'fault.encoder_dropout_mode', 'missing')),
    Fault('encoder frozen', 'fault.encoder_dropout leg2_length (freeze), mid-move',
          'the move aborts: encoder frozen, naming the axis',
          (R.ABORTED_ENCODER.value,), 'encoder of leg2_length frozen', 1.0,
          _set(names.NODE_DRIVER, 'fault.encoder_dropout', 'leg2_length')),
    Fault('axis stuck', 'fault.stuck_axis leg2_length, mid-move',
          'following error: drive fault, the move aborts naming the axis',
          (R.ABORTED_FAULT.value,), 'leg2_length', 1.0,
          _set(names.NODE_DRIVER, 'fault.stuck_axis', 'leg2_length')),
    Fault('drives off', '/leg_driver/enable false, mid-move',
          'the move aborts at once: drives disabled', (R.ABORTED_DRIVES_OFF.value,),
          'drives disabled during the move', 0.3, lambda cell: cell.enable(False)),
    Fault('driver killed', 'SIGKILL of leg_driver_node, mid-move',
          'the move aborts: leg driver not responding; new moves refused while it is gone',
          (R.ABORTED_DRIVER_LOST.value,), 'leg driver not responding', 0.5,
          lambda cell: cell.kill(DRIVER), after=_refused_while_driver_gone,
          restore=_restart(DRIVER)),
    Fault('tracker killed', 'SIGKILL of pose_measurement_node, mid-move (measured mode)',
          'the move aborts: laser tracker not responding', (R.ABORTED_TRACKER_LOST.value,),
          'laser tracker not responding', 1.0, lambda cell: cell.kill(TRACKER),
          mode='measured', restore=_restart(TRACKER)),
    Fault('tracker occluded', 'fault.occlusion_probability 1.0, mid-move (measured mode)',
          'the move aborts: laser tracker not responding', (R.ABORTED_TRACKER_LOST.value,),
          'laser tracker not responding', 1.0,
          _set(names.NODE_MEASUREMENT, 'fault.occlusion_probability', 1.0), mode='measured'),
    Fault('tracker outliers', 'fault.outlier_probability 0.8 before a move (measured mode)',
          'the robust fit rejects them and the move settles within tolerance, or it fails '
          'with a code: never success outside tolerance',
          (R.SUCCESS.value, R.ABORTED_TRACKER_INCONSISTENT.value,
           R.ABORTED_TRACKER_LOST.value, R.OUT_OF_TOLERANCE.value), '', 30.0,
          _set(names.NODE_MEASUREMENT, 'fault.outlier_probability', 0.8), mode='measured',
          mid_move=False),
    Fault('encoder noise burst', 'fault.noise_burst [50, 2 s] mid-move (measured mode)',
          'the move settles within tolerance (the closed loop is on the tracker); no false '
          'fault', (R.SUCCESS.value,), 'settled within tolerance', 30.0,
          _set(names.NODE_DRIVER, 'fault.noise_burst', [50.0, 2.0]), mode='measured'),
    Fault('uncommanded motion',
          f'fault.uncommanded_motion: the drives move leg1 by {UNCOMMANDED[1] * 1e3:g} mm on '
          'their own while the cell stands still',
          'the positioner\'s standstill monitoring: a fault naming the axis, the drives stopped '
          'short, the position unconfirmed; the next move succeeds, planned from the encoders',
          (R.UNCOMMANDED_MOTION.value,), 'uncommanded motion at standstill: leg1_length', 0.5,
          _set(names.NODE_DRIVER, 'fault.uncommanded_motion', list(UNCOMMANDED)),
          kind='standstill'),
    Fault('spoofed encoders',
          f'a second node publishes /legs/joint_states with leg1 {SPOOF_OFFSET * 1e3:g} mm off '
          f'({SPOOF_MESSAGES} messages at {1 / SPOOF_PERIOD:g} Hz) at standstill',
          'the positioner names the second publisher and ignores its messages: the estimate '
          'does not move, no fault', ('second_publisher',),
          f'second publisher on {names.JOINT_STATES}: /{CLIENT_NODE}', 1.0, kind='spoof',
          topic=names.JOINT_STATES),
    Fault('spoofed tracker',
          f'a second node publishes /metrology/pose {SPOOF_OFFSET * 1e3:g} mm off at standstill',
          'the positioner names the second publisher and ignores its messages: no fault',
          ('second_publisher',), f'second publisher on {names.MEASURED_POSE}: /{CLIENT_NODE}',
          1.0, kind='spoof', topic=names.MEASURED_POSE),
    Fault('positioner killed', 'SIGKILL of kinematics_node, mid-move; then started again',
          'the drives stop under control when its heartbeat falls silent (instead of finishing '
          'the trajectory unsupervised); the restarted positioner\'s first move succeeds',
          ('commander_silent',), 'commander /positioner silent', 1.0,
          lambda cell: cell.kill(POSITIONER), kind='commander',
          after=_first_move_after_restart, restore=_running(POSITIONER)),
    Fault('flood of calls', f'{FLOOD_CALLS} concurrent calls to every service of the cell',
          'every call answered (success, busy or a refusal)', (), '', 60.0, kind='flood',
          stops=False),
)


def fault(name: str) -> Fault:
    """The row of :data:`FAULTS` called ``name``."""
    found = next((f for f in FAULTS if f.name == name), None)
    if found is None:
        raise KeyError(f'no fault {name!r}; the matrix has: {", ".join(f.name for f in FAULTS)}')
    return found


def markdown_table(trials: dict[str, Sequence[Trial]] | None = None) -> str:
    """The matrix as the README's table (with measured reaction times when given)."""
    head = ['fault injected', 'expected reaction', 'result code', 'reason contains', 'bound']
    if trials:
        head.append('measured (median / max)')
    rows = ['| ' + ' | '.join(head) + ' |', '|' + ' --- |' * len(head)]
    for f in FAULTS:
        cells = [f'**{f.name}**: {f.injection}', f.reaction,
                 ' or '.join(f'`{c}`' for c in f.codes) or '—',
                 f'"{f.reason}"' if f.reason else '—', f'{f.bound_s:g} s']
        if trials:
            done = [t.reaction_s for t in trials.get(f.name, ())]
            cells.append(f'{np.median(done):.3f} / {max(done):.3f} s' if done else '—')
        rows.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(rows) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('faults', nargs='*', help='names of rows (default: all)')
    args = parser.parse_args(argv)
    chosen = [fault(n) for n in args.faults] or list(FAULTS)
    with tempfile.TemporaryDirectory(prefix='fault_matrix_') as tmp, FaultCell(Path(tmp)) as cell:
        cell.start()
        trials = [run_trial(cell, f) for f in chosen]
    for t in trials:
        print(f'{t.fault:24s} {t.reaction_s:7.3f} s  {t.code:28s} '
              f'{"ok" if t.ok else "; ".join(t.problems)}')
    return 0 if all(t.ok for t in trials) else 1


if __name__ == '__main__':
    sys.exit(main())
