"""The fault matrix: each fault injected into a running cell, the reaction expected of it
(result code, words of the reason, time bound), and a trial that injects it and measures what
happened, checking from the simulator's true joint states that the drives stopped and that no
axis went beyond its limits. Written against a
:class:`~positioning_cell.procedures.fault_port.FaultPort`: the live cell
(:mod:`positioning_cell.ros.fault_cell`) and the in-process one
(:mod:`positioning_cell.testing.instant_faults`) run the same trials and are judged by the same
rules here.

The README's "Fault matrix" table is :data:`FAULTS` (:func:`markdown_table`).
Reaction time: from the injection (just before the parameter call, the kill, the publish) to
the publication of the positioner's status carrying the result code (its source timestamp, so
that the client's own scheduling on a busy machine is not counted as the cell's): the driver's
answer for a trajectory sent to it directly; the driver's status for a silent commander; the
positioner's input status for a second publisher; the last reply for a flood of calls. For
motion nobody commanded, from the moment the true position passes the standstill tolerance.
The truth is read only to judge.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from functools import partial
from typing import Literal, NamedTuple

import numpy as np

from positioning_cell import names
from positioning_cell.motion.settings import LivenessSettings
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.parameters import RULE
from positioning_cell.polling import wait_until
from positioning_cell.procedures.fault_port import FaultPort, ParameterValue, Report
from positioning_cell.procedures.port import FloatArray, Moved, ProcedureError, Say
from positioning_cell.procedures.stopping import Stopped, StopSignal
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
#: The node a foreign message comes from: what the cell sees as its sender.
CLIENT_NODE = 'fault_matrix'
#: A positioner restarted after a SIGKILL hears the encoders within this (s): its start-up on
#: a busy machine, then until the killed participant's lease (5 s,
#: config/fastdds_loopback.xml) runs out, the driver does not send it its readings.
RESTART_HEARD_S = 30.0
#: A killed node is forgotten by the rest of the cell within this (s): the lease of its DDS
#: participant (5 s, config/fastdds_loopback.xml) on a busy machine.
FORGET_S = 30.0
#: How far ahead the foreign trajectory is stamped (the issue's probe: run 4 s later).
AHEAD_S = 4.0
#: Where the foreign trajectory takes the axes: leg 1, leg 2 lengths (m), theta 1 (rad).
BEYOND = {0: 0.240, 1: 0.150, 3: 1.2}
#: A spoofed input: how far it is off, how many messages at what period.
SPOOF_OFFSET = 1.7e-3
SPOOF_MESSAGES, SPOOF_PERIOD = 50, 0.01
#: The motion nobody commands: [axis index, distance m] (fault.uncommanded_motion). At a fifth
#: of the leg's speed limit it lasts 0.7 s: longer than its leaving the standstill tolerance
#: (~0.04 s in) plus the reaction bound (0.5 s), so a reaction in time stops it short of its
#: end. (2 mm lasted 0.3 s: on a loaded machine a reaction in time came after 1.8 mm of it.)
UNCOMMANDED = (0.0, 6e-3)
#: Attempts of a trial whose fault landed after the motion.
ATTEMPTS = 3
#: The faults every trial starts without: (node, parameter, value).
CLEARED: tuple[tuple[str, str, ParameterValue], ...] = (
    (names.NODE_DRIVER, 'fault.encoder_dropout', ''),
    (names.NODE_DRIVER, 'fault.stuck_axis', ''),
    (names.NODE_DRIVER, 'fault.encoder_dropout_mode', 'freeze'),
    (names.NODE_DRIVER, 'fault.noise_burst', [1.0, 0.0]),
    (names.NODE_DRIVER, 'fault.uncommanded_motion', [0.0, 0.0]),
    (names.NODE_MEASUREMENT, 'fault.occlusion_probability', 0.0),
    (names.NODE_MEASUREMENT, 'fault.outlier_probability', 0.0))


@dataclass
class Trial:
    """What one trial of a fault gave: the result ``code`` and ``reason`` the cell reported,
    ``reaction_s`` (injection → that report), ``stopped_s`` (injection → all axes at rest; None
    when not measured), ``within_limits`` (every true joint position inside the stroke and
    angle range), ``problems`` (each way the reaction differed from the expected one but its
    time), ``late`` (the reaction later than the fault's bound: what a loaded machine alone
    can also cause, judged where the timing is under test), ``inject_s`` (how long the
    injection itself took)."""

    fault: str
    code: str = ''
    reason: str = ''
    reaction_s: float = math.nan
    stopped_s: float | None = None
    within_limits: bool = True
    problems: list[str] = field(default_factory=list)
    inject_s: float = 0.0
    late: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """The reaction was the expected one, in time."""
        return not self.problems and not self.late

    def in_time(self, bound_s: float) -> None:
        """Note the reaction as late when it came after ``bound_s``."""
        if not self.reaction_s <= bound_s:
            self.late.append(f'reaction {self.reaction_s:.3f} s > {bound_s} s')


# -- injections -------------------------------------------------------------------------------
class SetParameter(NamedTuple):
    """Set ``node``'s parameter ``name`` to ``value``."""

    node: str
    name: str
    value: ParameterValue


class Kill(NamedTuple):
    """Kill ``node`` (a crash)."""

    node: str


class DrivesOff(NamedTuple):
    """Switch the drives off."""


Injection = SetParameter | Kill | DrivesOff


def inject(port: FaultPort, injection: Injection | None) -> None:
    """Do ``injection`` on ``port`` (None: nothing)."""
    if isinstance(injection, SetParameter):
        port.set_parameter(*injection)
    elif isinstance(injection, Kill):
        port.kill(injection.node)
    elif isinstance(injection, DrivesOff):
        port.enable_drives(False)


def _nothing(port: FaultPort) -> None:
    return None


def _no_check(port: FaultPort, trial: Trial) -> None:
    return None


Kind = Literal['move', 'trajectory', 'flood', 'standstill', 'spoof', 'commander']


@dataclass(frozen=True)
class Fault:
    """One row of the matrix: ``injection`` (the words) done by ``inject`` mid-move, or just
    before the move when not ``mid_move``, ``prepare`` before the move, in compensation
    ``mode``; expected: ``reaction``, a result code among ``codes`` with ``reason`` in its
    reason within ``bound_s`` s, the drives at rest after it (``stops``), and what ``after``
    checks next; ``restore`` puts the cell back. ``kind`` picks the trial: ``move`` (a move
    with the fault), ``trajectory`` (a trajectory sent to the driver directly by another
    node), ``flood`` (concurrent calls to every service), ``standstill`` (motion while nothing
    is commanded), ``spoof`` (a second publisher on an input of the positioner: ``topic``),
    ``commander`` (the positioner killed mid-move)."""

    name: str
    injection: str
    reaction: str
    codes: tuple[str, ...]
    reason: str
    bound_s: float
    inject: Injection | None = None
    prepare: tuple[Injection, ...] = ()
    mode: str = 'none'
    mid_move: bool = True
    stops: bool = True
    after: Callable[[FaultPort, Trial], None] = _no_check
    restore: Callable[[FaultPort], None] = _nothing
    kind: Kind = 'move'
    topic: str = ''


# -- the cell's state, as the trials judge it -------------------------------------------------
def goal(port: FaultPort, k: int) -> tuple[FloatArray, FloatArray]:
    """Trial goal ``k`` (0: below home, 1: above): position m, quaternion, base frame."""
    mech = port.positioner_settings.mechanism
    offset = np.array([0.0, 0.0, SPAN if k else -SPAN])
    return np.asarray(mech.home_position) + offset, np.asarray(mech.home_quaternion, float)


def ready(port: FaultPort, mode: str) -> None:
    """No fault injected, drives enabled, compensation ``mode``, referenced and homed when
    not, the positioner accepting both trial goals, and the axes at rest."""
    for node, name, value in CLEARED:
        port.set_parameter(node, name, value)
    port.enable_drives(True)
    port.set_mode(mode)
    for k in (0, 1):
        wait_until(partial(_accepts, port, *goal(port, k)), 60.0,
                   'the positioner to accept the trial goals')
    # homing (after a restarted driver) can end with an axis still settling: motion seen in
    # the trial must be the trial's own
    settling = port.monotonic()
    wait_until(lambda: at_rest(port, settling), 30.0, 'the axes to come to rest')


def _accepts(port: FaultPort, position: FloatArray, quaternion: FloatArray) -> bool:
    """The positioner's check accepts the goal; refused as not referenced (the drives were
    restarted or never homed): home first."""
    checked = port.check(position, quaternion)
    if checked.success:
        return True
    if checked.code == ResultCode.REFUSED_NOT_REFERENCED.value:
        homed = port.home()
        if not homed.success:
            raise ProcedureError(f'homing failed: {homed.reason}', homed.code)
    return False


def set_liveness(port: FaultPort, on: bool) -> None:
    """The positioner's liveness rules as configured (``on``), or as lax as their parameters
    allow (the baseline of benchmarks/faults.py: only the timeouts remain)."""
    live = port.positioner_settings.liveness
    for name, lax in LAX_LIVENESS.items():
        port.set_parameter(names.NODE_POSITIONER, f'liveness.{name}',
                           float(getattr(live, name) if on else lax))


class _Move(NamedTuple):
    """A move running in a thread: when it started (port clock), the thread, its goal, and
    its outcome once it ended."""

    started: float
    thread: threading.Thread
    goal: tuple[FloatArray, FloatArray]
    outcome: list[Moved]


def start_move(port: FaultPort) -> _Move:
    """Start a move to the trial goal farther from where the positioner estimates the
    platform (a goal it is already at succeeds without moving) in a thread."""
    seen = port.estimates(-math.inf)
    here = seen[-1] if len(seen) else np.asarray(port.positioner_settings.mechanism
                                                 .home_position)
    target = max((goal(port, k) for k in (0, 1)),
                 key=lambda g: float(np.linalg.norm(g[0] - here)))
    outcome: list[Moved] = []
    thread = threading.Thread(target=lambda: outcome.append(port.move(*target)), daemon=True,
                              name='fault-trial-move')
    started = port.monotonic()
    thread.start()
    return _Move(started, thread, target, outcome)


def _moving_rows(velocities: FloatArray) -> np.ndarray:
    """Per true joint state (k, 6): some axis faster than REST_SPEED."""
    return np.asarray(np.any(np.abs(velocities[:, :3]) > REST_SPEED[0], axis=1)
                      | np.any(np.abs(velocities[:, 3:]) > REST_SPEED[1], axis=1))


def moving(port: FaultPort, since: float) -> bool:
    """One of the last 20 true joint states received after ``since`` shows an axis moving."""
    return bool(_moving_rows(port.true_states(since).velocities[-20:]).any())


def at_rest(port: FaultPort, since: float) -> bool:
    """Every axis at rest in the true joint states of the last REST_WINDOW s, those received
    after ``since`` spanning at least that window."""
    states = port.true_states(since)
    if not len(states.times) or states.times[-1] - states.times[0] < REST_WINDOW:
        return False
    recent = states.times >= states.times[-1] - REST_WINDOW
    return not _moving_rows(states.velocities[recent]).any()


def rest_time(port: FaultPort, since: float) -> float | None:
    """Receipt time from which every axis stayed at rest for REST_WINDOW s (true joint states
    received after ``since``); None if they did not (yet)."""
    states = port.true_states(since)
    still = ~_moving_rows(states.velocities)
    if not still.any():
        return None
    index = np.arange(still.size)
    begins = still & np.concatenate([[True], ~still[:-1]])
    run_start = np.maximum.accumulate(np.where(begins, index, 0))
    held = still & (states.times - states.times[run_start] >= REST_WINDOW)
    if not held.any():
        return None
    return float(states.times[run_start[int(np.argmax(held))]])


def within_limits(port: FaultPort, since: float) -> bool:
    """Every true joint position received after ``since`` inside the stroke and the
    second-U-angle range (1 nm / 1 nrad of slack)."""
    m, eps = port.positioner_settings.mechanism, 1e-9
    lo = np.array([m.length_min] * 3 + [m.theta_min] * 3) - eps
    hi = np.array([m.length_max] * 3 + [m.theta_max] * 3) + eps
    p = port.true_states(since).positions
    return bool(np.all((p >= lo) & (p <= hi)))


# -- trials -----------------------------------------------------------------------------------
class LandedLateError(Exception):
    """The injection returned only after the motion had ended: the move rightly succeeded,
    and the trial did not test the fault mid-move (on a loaded machine a parameter call can
    take longer than the rest of the move)."""


class _NeverMovedError(LandedLateError):
    """The trial's move ended before any axis moved (refused: a liveness rule on the wall
    clock, such as the tracker's silence in ``measured`` mode, can trip on a loaded machine
    between the trial's readiness check and the move): no fault was tested."""


def _wait_for_motion(port: FaultPort, move: _Move) -> None:
    """Wait until an axis moves under ``move``; _NeverMovedError naming the move's outcome
    when it ended first (TimeoutError after 30 s of neither)."""
    wait_until(lambda: moving(port, move.started) or not move.thread.is_alive(), 30.0,
               'the axes to move')
    if not moving(port, move.started):
        move.thread.join(timeout=1.0)
        outcome = move.outcome[0] if move.outcome else None
        raise _NeverMovedError('the move ended before any axis moved: '
                               + (f'{outcome.code}: {outcome.reason}' if outcome else
                                  'no outcome'))


def run_trial(port: FaultPort, fault: Fault) -> Trial:
    """One trial of ``fault`` on ``port`` (ready first, restored after); a trial whose fault
    landed after the motion is run again, up to ATTEMPTS times."""
    for attempt in range(1, ATTEMPTS + 1):
        trial = Trial(fault.name)
        ready(port, fault.mode)
        began = port.monotonic()
        try:
            TRIALS[fault.kind](port, fault, trial)
            fault.after(port, trial)
        except LandedLateError as late:
            if attempt < ATTEMPTS:
                continue
            trial.problems.append(f'{late} in all {ATTEMPTS} attempts')
        except TimeoutError as err:
            trial.problems.append(str(err))
        finally:
            trial.within_limits = within_limits(port, began)
            if not trial.within_limits:
                trial.problems.append('an axis went beyond its limit')
            fault.restore(port)
        return trial
    raise AssertionError('unreachable')


def run_matrix(port: FaultPort, faults: Sequence[Fault], say: Say,
               stop: threading.Event | None = None) -> list[Trial]:
    """One trial of each of ``faults`` on ``port``, a line said for each; ``stop`` set ends
    the run between trials (Stopped; the drives are stopped at once)."""
    trials: list[Trial] = []
    with StopSignal(stop, port.stop) as signal:
        for f in faults:
            signal.check()
            trial = run_trial(port, f)
            say(line(trial))
            trials.append(trial)
    return trials


def line(trial: Trial) -> str:
    """One line for people: the fault, the reaction time, the code, ok or the problems."""
    return (f'{trial.fault:24s} {trial.reaction_s:7.3f} s  {trial.code:28s} '
            f'{"ok" if trial.ok else "; ".join(trial.problems + trial.late)}')


def judge(trial: Trial, fault: Fault) -> None:
    """The result code among the fault's, its words in the reason, the reaction in time."""
    if trial.code not in fault.codes:
        trial.problems.append(f'result {trial.code!r}, expected {" or ".join(fault.codes)}')
    if fault.reason not in trial.reason:
        trial.problems.append(f'reason {trial.reason!r} lacks {fault.reason!r}')
    trial.in_time(fault.bound_s)


def _take(trial: Trial, report: Report, since: float) -> float:
    """Note ``report`` as the trial's result, reacted to from ``since``; its time."""
    trial.code, trial.reason, trial.reaction_s = report.code, report.message, report.time - since
    return report.time


def _move_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """A move with the fault injected (mid-move, or just before it), the result, the axes at
    rest after a failure, the true pose within tolerance after a success in ``measured``."""
    for step in fault.prepare:
        inject(port, step)
    injected = port.monotonic()
    if not fault.mid_move:
        inject(port, fault.inject)
    move = start_move(port)
    if fault.mid_move:
        _wait_for_motion(port, move)
        injected = port.monotonic()
        inject(port, fault.inject)
    trial.inject_s = port.monotonic() - injected
    injection_done = injected + trial.inject_s
    received = _take(trial, wait_until(lambda: port.result_after(move.started),
                                       fault.bound_s + 60.0, 'the result of the move'),
                     injected)
    move.thread.join(timeout=60.0)
    success = trial.code == ResultCode.SUCCESS.value
    if (fault.mid_move and success and ResultCode.SUCCESS.value not in fault.codes
            and not _moving_rows(port.true_states(injection_done - 0.02).velocities[:3]).any()):
        raise LandedLateError(f'the injection took {trial.inject_s:.2f} s and ended after the '
                               'motion')
    judge(trial, fault)
    if success and fault.mode == 'measured':
        _judge_success(port, trial, move.goal[0], received)
    elif fault.stops:
        _judge_stop(port, trial, injected, received)


def _judge_stop(port: FaultPort, trial: Trial, injected: float, received: float) -> None:
    """The axes at rest within STOP_WITHIN s of the reaction; a killed driver takes the
    simulated drives with it (no true joint states after it)."""
    if port.running(names.NODE_DRIVER):
        rest = wait_until(lambda: rest_time(port, injected) or
                          (port.monotonic() > received + STOP_WITHIN + 1.0 and -1.0),
                          STOP_WITHIN + 5.0, 'the axes to come to rest')
        trial.stopped_s = None if rest < 0 else max(rest - injected, 0.0)
        if rest < 0 or rest > received + STOP_WITHIN:
            trial.problems.append(f'drives not at rest within {STOP_WITHIN} s of the reaction')
        return
    trial.stopped_s = 0.0
    if len(port.true_states(injected + 0.1).times):
        trial.problems.append('true joint states after the driver was killed')


def _judge_success(port: FaultPort, trial: Trial, target: FloatArray, received: float) -> None:
    """A success in ``measured`` mode (settled within tolerance as the tracker sees it): the
    true position within the goal tolerance plus three of the tracker's stated sigmas. (In
    ``none`` and ``model`` the tolerance holds for the encoders' estimate, and the truth differs
    from it by the uncompensated clearance.)"""
    true_position = wait_until(lambda: [p for p in [port.true_position_after(received)]
                                        if p is not None], 10.0, 'a true pose')[0]
    error = float(np.linalg.norm(true_position - target))
    limit = port.positioner_settings.goal_tolerance.position + 3.0 * port.tracker_sigma()
    if not error <= limit:
        trial.problems.append(f'success, but the true position is {error * 1e6:.1f} um from '
                              f'the goal (tolerance + 3 sigma: {limit * 1e6:.1f} um)')


def _trajectory_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """A trajectory from another node beyond the axis limits at a legal speed, stamped
    AHEAD_S s ahead: refused as foreign, naming the sender, and the axes hold, also after the
    stamp's time has come. It starts with the axes at rest (after the homing of the first
    trial the servos still close the last 0.1 µm: not motion the trajectory caused)."""
    _at_rest(port)
    recent = wait_until(lambda: len(port.true_states(port.monotonic() - 0.5).times) > 0 and
                        port.true_states(port.monotonic() - 0.5), 10.0, 'true joint states')
    beyond = recent.positions[-1].copy()
    beyond[list(BEYOND)] = list(BEYOND.values())
    inject(port, fault.inject)
    sent, answer = port.foreign_trajectory(beyond, AHEAD_S, 10.0)
    received = _take(trial, answer, sent)
    judge(trial, fault)
    wait_until(lambda: len(port.true_states(received + AHEAD_S + 0.5).times), AHEAD_S + 10.0,
               'true joint states after the stamp')
    held = port.true_states(received).positions
    spread = float(np.ptp(held, axis=0).max()) if len(held) else 0.0
    if spread > 1e-7:
        trial.problems.append(f'the axes moved {spread:.2e} after the refusal')
    trial.stopped_s = 0.0


def _at_rest(port: FaultPort) -> None:
    wait_until(lambda: rest_time(port, port.monotonic() - 1.0), 10.0, 'the axes at rest')


def _standstill_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """Motion nobody commanded while the cell stands still: the positioner reports it
    (uncommanded_motion) within the bound of the true position leaving the standstill
    tolerance, the drives stop short of the motion's end, and the next move succeeds,
    planned from where the encoders are."""
    _at_rest(port)
    rest = port.true_states(port.monotonic() - 0.2).positions[-1]
    injected = port.monotonic()
    inject(port, fault.inject)
    trial.inject_s = port.monotonic() - injected
    received = _take(trial, wait_until(lambda: port.result_after(injected),
                                       fault.bound_s + 10.0, 'the positioner to react'),
                     injected)
    after = port.true_states(injected)
    tolerance = port.positioner_settings.standstill.joint_tolerance
    off = np.any(np.abs(after.positions - rest) > tolerance, axis=1)
    if off.any():
        beyond = float(after.times[int(np.argmax(off))])
    else:
        trial.problems.append('reported before the true motion passed the tolerance')
        beyond = received
    trial.reaction_s = received - beyond
    judge(trial, fault)
    _judge_stop(port, trial, beyond, received)
    moved = float(np.max(np.abs(port.true_states(injected).positions - rest), initial=0.0))
    if moved > 0.9 * abs(UNCOMMANDED[1]):  # a late reaction explains it; one in time not
        (trial.late or trial.problems).append(f'the axis moved {moved * 1e3:.3f} mm: the '
                                              'drives were not stopped short of the motion')
    _next_move_succeeds(port, trial, 'the next move')


def _next_move_succeeds(port: FaultPort, trial: Trial, what: str) -> None:
    move = start_move(port)
    move.thread.join(timeout=120.0)
    result = port.result_after(move.started)
    if result is None or result.code != ResultCode.SUCCESS.value:
        trial.problems.append(f'{what} gave {result}')


def _spoof_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """A second publisher on an input of the positioner, SPOOF_MESSAGES messages SPOOF_OFFSET
    off the truth while the cell stands still: the positioner names it within the bound, and
    neither its estimate moves nor a fault follows."""
    _at_rest(port)
    seen = port.estimates(-math.inf)
    before = seen[-1] if len(seen) else None
    injected = port.spoof(fault.topic, SPOOF_OFFSET, SPOOF_MESSAGES, SPOOF_PERIOD)
    words = f'second publisher on {fault.topic}: /{CLIENT_NODE}'
    report = wait_until(lambda: port.status_after(names.STATUS_POSITIONER_INPUTS, injected,
                                                  words),
                        fault.bound_s + 10.0, f'the positioner to report {words}')
    _take(trial, report._replace(code='second_publisher'), injected)
    judge(trial, fault)
    estimates = port.estimates(injected)
    if before is not None and len(estimates):
        jump = float(np.max(np.linalg.norm(estimates - before, axis=1)))
        if jump > 10e-6:
            trial.problems.append(f'the estimate moved {jump * 1e6:.1f} um')
    late = port.result_after(injected)
    if late is not None:
        trial.problems.append(f'a result {late.code!r} followed: {late.message}')
    trial.stopped_s = 0.0


def _commander_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """The positioner killed mid-move: the drives stop under control when its heartbeat falls
    silent (the driver's status says so) instead of finishing the trajectory unsupervised."""
    move = start_move(port)
    _wait_for_motion(port, move)
    injected = port.monotonic()
    inject(port, fault.inject)
    report = silence_stop(port, injected, fault.bound_s)
    received = _take(trial, report._replace(code='commander_silent'), injected)
    judge(trial, fault)
    _judge_stop(port, trial, injected, received)


def silence_stop(port: FaultPort, killed: float, bound_s: float) -> Report:
    """The leg driver's status saying it stopped the axes because its commander, killed at
    ``killed`` (port clock, s), fell silent. LandedLateError when the axes came to rest
    without it within the driver's heartbeat timeout of the kill and no such status came in
    ``bound_s`` s after: the move ended before the silence counted, so the drives rightly
    finished it (on a loaded machine the kill can land at the very end of the move).
    TimeoutError when neither comes (e.g. the drives finished a longer move unsupervised)."""
    def seen() -> Report | None:
        report = port.status_after(names.STATUS_DRIVER, killed, 'silent')
        if report is not None:
            return report
        rest = rest_time(port, killed)
        if (rest is not None and rest <= killed + port.heartbeat_timeout
                and port.monotonic() > rest + bound_s):
            raise LandedLateError(f'the axes were at rest {rest - killed:.2f} s after the '
                                   'kill, within the driver\'s heartbeat timeout '
                                   f'({port.heartbeat_timeout:g} s): nothing to stop')
        return None

    found: Report = wait_until(seen, bound_s + 10.0, 'the driver to stop the axes')
    return found


def _flood_trial(port: FaultPort, fault: Fault, trial: Trial) -> None:
    """FLOOD_CALLS concurrent calls to every service of the cell, all at once: every one
    answered (success, busy or a refusal) within the bound."""
    flood = port.flood(FLOOD_CALLS, fault.bound_s)
    calls, answered = sum(flood.calls.values()), sum(flood.answered.values())
    trial.reaction_s = flood.elapsed
    trial.code = f'{answered}/{calls} answered'
    trial.reason = ', '.join(f'{name} {flood.answered[name]}' for name in flood.calls)
    if answered < calls:
        trial.problems.append(f'{calls - answered} of {calls} calls unanswered after '
                              f'{fault.bound_s} s')
    trial.in_time(fault.bound_s)


TRIALS: dict[Kind, Callable[[FaultPort, Fault, Trial], None]] = {
    'move': _move_trial, 'trajectory': _trajectory_trial, 'flood': _flood_trial,
    'standstill': _standstill_trial, 'spoof': _spoof_trial, 'commander': _commander_trial}


# -- what follows and what restores ------------------------------------------------------------
def _restart(node: str) -> Callable[[FaultPort], None]:
    """Restore after ``node`` was killed: started again once the cell has forgotten the
    killed process (a process started in its place within the others' lease on it, 5 s, is
    not sent their data: the positioner's homing then timed out waiting for the restarted
    driver's answer, or found its joint states silent), then ready."""
    def restore(port: FaultPort) -> None:
        wait_until(lambda: port.forgotten(node), FORGET_S, f'the killed {node} forgotten')
        port.restart(node)
        ready(port, 'none')
    return restore


def _running(node: str) -> Callable[[FaultPort], None]:
    def restore(port: FaultPort) -> None:
        if not port.running(node):
            port.restart(node)
    return restore


def _first_move_after_restart(port: FaultPort, trial: Trial) -> None:
    """The positioner started again beside the running driver hears the encoders within
    :data:`RESTART_HEARD_S` (its first pose estimate), and its first move then succeeds (it
    plans from where the encoders are). Within the DDS lease of the killed participant (5 s in
    the cell's profile) the new process is not yet sent the driver's readings."""
    restarted = port.monotonic()
    port.restart(names.NODE_POSITIONER)
    try:
        wait_until(lambda: len(port.estimates(restarted)) > 0, RESTART_HEARD_S,
                   "the restarted positioner's first pose estimate")
    except TimeoutError as err:
        trial.problems.append(str(err))
        return
    _next_move_succeeds(port, trial, 'the first move of the restarted positioner')


def _refused_while_driver_gone(port: FaultPort, trial: Trial) -> None:
    """After the driver was killed: a new move is refused as silent."""
    asked = port.monotonic()
    port.move(*goal(port, 0))
    refusal = wait_until(lambda: port.result_after(asked), 30.0, 'the refusal')
    if refusal.code != ResultCode.REFUSED_DRIVER_SILENT.value:
        trial.problems.append(f'a move while the driver is gone gave {refusal.code!r}: '
                              f'{refusal.message}')


def _driver(name: str, value: ParameterValue) -> SetParameter:
    return SetParameter(names.NODE_DRIVER, name, value)


def _tracker(name: str, value: ParameterValue) -> SetParameter:
    return SetParameter(names.NODE_MEASUREMENT, name, value)


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
          _driver('fault.encoder_dropout', 'leg2_length'),
          prepare=(_driver('fault.encoder_dropout_mode', 'missing'),)),
    Fault('encoder frozen', 'fault.encoder_dropout leg2_length (freeze), mid-move',
          'the move aborts: encoder frozen, naming the axis',
          (R.ABORTED_ENCODER.value,), 'encoder of leg2_length frozen', 1.0,
          _driver('fault.encoder_dropout', 'leg2_length')),
    Fault('axis stuck', 'fault.stuck_axis leg2_length, mid-move',
          'following error: drive fault, the move aborts naming the axis',
          (R.ABORTED_FAULT.value,), 'leg2_length', 1.0,
          _driver('fault.stuck_axis', 'leg2_length')),
    Fault('drives off', '/leg_driver/enable false, mid-move',
          'the move aborts at once: drives disabled', (R.ABORTED_DRIVES_OFF.value,),
          'drives disabled during the move', 0.3, DrivesOff()),
    Fault('driver killed', 'SIGKILL of leg_driver_node, mid-move',
          'the move aborts: leg driver not responding; new moves refused while it is gone',
          (R.ABORTED_DRIVER_LOST.value,), 'leg driver not responding', 0.5,
          Kill(names.NODE_DRIVER), after=_refused_while_driver_gone,
          restore=_restart(names.NODE_DRIVER)),
    Fault('tracker killed', 'SIGKILL of pose_measurement_node, mid-move (measured mode)',
          'the move aborts: laser tracker not responding', (R.ABORTED_TRACKER_LOST.value,),
          'laser tracker not responding', 1.0, Kill(names.NODE_MEASUREMENT),
          mode='measured', restore=_restart(names.NODE_MEASUREMENT)),
    Fault('tracker occluded', 'fault.occlusion_probability 1.0, mid-move (measured mode)',
          'the move aborts: laser tracker not responding', (R.ABORTED_TRACKER_LOST.value,),
          'laser tracker not responding', 1.0,
          _tracker('fault.occlusion_probability', 1.0), mode='measured'),
    Fault('tracker outliers', 'fault.outlier_probability 0.8 before a move (measured mode)',
          'the robust fit rejects them and the move settles within tolerance, or it fails '
          'with a code: never success outside tolerance',
          (R.SUCCESS.value, R.ABORTED_TRACKER_INCONSISTENT.value,
           R.ABORTED_TRACKER_LOST.value, R.OUT_OF_TOLERANCE.value), '', 30.0,
          _tracker('fault.outlier_probability', 0.8), mode='measured', mid_move=False),
    Fault('encoder noise burst', 'fault.noise_burst [50, 2 s] mid-move (measured mode)',
          'the move settles within tolerance (the closed loop is on the tracker); no false '
          'fault', (R.SUCCESS.value,), 'settled within tolerance', 30.0,
          _driver('fault.noise_burst', [50.0, 2.0]), mode='measured'),
    Fault('uncommanded motion',
          f'fault.uncommanded_motion: the drives move leg1 by {UNCOMMANDED[1] * 1e3:g} mm on '
          'their own while the cell stands still',
          'the positioner\'s standstill monitoring: a fault naming the axis (or the tracker\'s '
          'measure, when it sees the platform leave its rest pose first), the drives stopped '
          'short, the position unconfirmed; the next move succeeds, planned from the encoders',
          (R.UNCOMMANDED_MOTION.value,), 'uncommanded motion at standstill: ', 0.5,
          _driver('fault.uncommanded_motion', list(UNCOMMANDED)), kind='standstill'),
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
          Kill(names.NODE_POSITIONER), kind='commander',
          after=_first_move_after_restart, restore=_running(names.NODE_POSITIONER)),
    Fault('flood of calls', f'{FLOOD_CALLS} concurrent calls to every service of the cell',
          'every call answered (success, busy or a refusal)', (), '', 60.0, kind='flood',
          stops=False),
)


def fault(name: str) -> Fault:
    """The row of :data:`FAULTS` called ``name`` (KeyError naming the rows otherwise)."""
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


__all__ = ['CLIENT_NODE', 'FAULTS', 'DrivesOff', 'Fault', 'Injection', 'Kill', 'SetParameter',
           'Stopped', 'Trial', 'fault', 'markdown_table', 'ready', 'run_matrix', 'run_trial',
           'set_liveness']
