"""The fault matrix in process: :class:`InstantFaultPort`, a
:class:`~positioning_cell.procedures.fault_port.FaultPort` on the positioner's own move logic
(:class:`~positioning_cell.motion.mover.Mover`, unchanged) driving the leg driver's own logic
(:class:`~positioning_cell.sim.drives.LegDriver`: servos, encoders, the injected drive faults,
the commander's heartbeat watch, the foreign-sender rule) and the simulated tracker with its
injected faults, all on the monotonic clock, without DDS. A thread does what the nodes' timers
do: the driver's physics step and its encoder publication (``publish_every``), the
positioner's heartbeat and its pose estimate (``pose_rate_hz``, which feeds the standstill
watch), the driver's status to the positioner. Killing a node stops its part; restarting the
driver starts it afresh (at home, unreferenced, the configured faults), as the live
simulator does. No DDS: a second publisher and a flood of calls cannot be made here
(:class:`~positioning_cell.procedures.fault_port.Unsupported`). Joints in ``JOINT_NAMES``
order, m and rad."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell import names
from positioning_cell.config import config_path, flatten, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.metrology.fit import TooFewTargetsError
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.moves.machine import Answer, JointReading, Machine, Measurement
from positioning_cell.moves.outcomes import MoveAbortedError, ResultCode, State
from positioning_cell.moves.trajectory import Trajectory
from positioning_cell.parameters import parse, to_params
from positioning_cell.procedures.fault_port import (
    Flood,
    ParameterValue,
    ProcedureError,
    Report,
    TrueStates,
    Unsupported,
)
from positioning_cell.procedures.fault_trials import CLIENT_NODE
from positioning_cell.procedures.port import FloatArray, Moved
from positioning_cell.sim.drives import DriverSettings, LegDriver
from positioning_cell.sim.guard import TrajectoryRefusedError
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator
from positioning_cell.sim.tracker import observe
from positioning_cell.testing.instant_port import InstantPort

#: What is kept of each stream.
KEPT = 20_000
#: The nodes of the cell in process.
NODES = (names.NODE_POSITIONER, names.NODE_DRIVER, names.NODE_MEASUREMENT)


def updated(settings: Any, name: str, value: ParameterValue) -> Any:
    """``settings`` with the dotted parameter ``name`` set (ProcedureError: refused)."""
    try:
        return parse(type(settings), {**flatten(to_params(settings)), name: value})
    except ConfigError as err:
        raise ProcedureError(f'{name} = {value!r} refused: {err}') from err


class InstantFaultPort(InstantPort):
    """The cell in process (module docstring): the simulator ``sim`` (located), a positioner
    with ``settings``, drives with ``driver``; coordinate systems in ``folder``. A context
    manager: :meth:`close` ends the thread."""

    def __init__(self, sim: PoseMeasurementSimulator, settings: PositionerSettings,
                 driver: DriverSettings, folder: Path, seed: int = 2) -> None:
        super().__init__(sim, settings, folder, seed)
        self._configured, self._driver_settings = settings, driver
        self._lock = threading.Lock()
        self._alive = dict.fromkeys(NODES, True)
        self._generation = 0
        self.drives = LegDriver(driver, time.monotonic())
        self._truth: list[tuple[float, FloatArray, FloatArray]] = []
        self._answers: list[Answer] = []
        self._results: list[Report] = []
        self._driver_reports: list[Report] = []
        self._estimates: list[tuple[float, FloatArray]] = []
        self._faults = sim.settings.fault
        self._tracked = time.monotonic()
        self._sigma = float('nan')
        self._start_positioner(settings, self._machine(self._generation))
        self._done = threading.Event()
        self._status: dict[str, str] | None = None
        self._threads = [threading.Thread(target=run, daemon=True, name=f'instant-{run.__name__}')
                         for run in (self._nodes, self._positioner)]
        for thread in self._threads:
            thread.start()

    @classmethod
    def configured(cls, folder: Path, config: Path | None = None,
                   seed: int = 2) -> InstantFaultPort:
        """The cell of a parameter file (default: the shipped ``config/cell.yaml``)."""
        params = load_parameter_file(config or config_path())
        sim = PoseMeasurementSimulator(parse(PoseMeasurementSettings,
                                             node_parameters(params, names.NODE_MEASUREMENT)))
        return cls(sim, parse(PositionerSettings, node_parameters(params,
                                                                 names.NODE_POSITIONER)),
                   parse(DriverSettings, node_parameters(params, names.NODE_DRIVER)), folder,
                   seed)

    def close(self) -> None:
        """End the nodes' thread."""
        self._done.set()
        for thread in self._threads:
            thread.join(timeout=5.0)

    def __enter__(self) -> InstantFaultPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what the nodes' timers do --------------------------------------------------------------
    def _nodes(self) -> None:
        """The driver's timer: its physics step, the positioner's heartbeat (a timer of its
        own live, never held up by the pose estimate)."""
        period = 1.0 / self._driver_settings.physics_rate
        while not self._done.wait(period):
            status = self._step(time.monotonic())
            with self._lock:
                self._status = status

    def _positioner(self) -> None:
        """The positioner's timers: the driver's status taken, the pose estimate (which feeds
        the standstill watch)."""
        period = 1.0 / self._configured.pose_rate_hz
        while not self._done.wait(period):
            if not self._alive[names.NODE_POSITIONER]:
                continue
            with self._lock:
                status = self._status
            mover = self.mover
            if status is not None:
                mover.driver_status(status)
            estimate = mover.estimate_pose()
            if estimate is not None:
                with self._lock:
                    self._estimates.append((time.monotonic(), estimate.position))
                    del self._estimates[:-KEPT]

    def _step(self, now: float) -> dict[str, str] | None:
        """The driver's physics step, its publication and its status (None: it is dead)."""
        with self._lock:
            if not self._alive[names.NODE_DRIVER]:
                return None
            positioner = self._alive[names.NODE_POSITIONER]
            if positioner:
                self.drives.heartbeat(now)
            self._graph(positioner)
            self._advance(now, publish=False)
            _, message, values = self.drives.status()
        return {**{k: str(v) for k, v in values.items()}, 'message': message}

    def _graph(self, positioner: bool) -> None:
        """The driver's view of the command topic's publishers (under the lock): the live
        positioner's, with a GID of its own for each life, and the foreign senders it has
        noted (in process nothing takes them out of the graph)."""
        mine = [('/' + names.NODE_POSITIONER, f'{self._generation:032x}')] if positioner else []
        self.drives.publishers(mine + [(name, name) for name in self.drives.foreign])

    def _advance(self, now: float, publish: bool) -> JointReading | None:
        """Step the drives to ``now`` (under the lock): their events reported, the true state
        kept at each publication (``publish``: one now); the encoder reading published."""
        drives = self.drives
        step = drives.step(now)
        if step.fault is not None:
            self._report(now, step.fault.message())
        if step.stopped is not None:
            self._report(now, step.stopped, step.stopped)
        if not (publish or step.publish):
            return None
        reading, state = drives.readings()
        self._truth.append((now, state.position.copy(), state.velocity.copy()))
        del self._truth[:-KEPT]
        self.cell.position = state.position.copy()
        return JointReading(reading.position, reading.velocity)

    def _report(self, now: float, event: str, level: str | None = None) -> None:
        """The driver's status after ``event`` (under the lock)."""
        _, message, _ = self.drives.status(event, 'error' if level else None)
        self._driver_reports.append(Report(now, '', message))

    # -- the machine the positioner drives ------------------------------------------------------
    def _machine(self, generation: int) -> Machine:
        """The positioner's world; inert once that positioner was killed (``generation``)."""
        def alive() -> bool:
            return generation == self._generation and self._alive[names.NODE_POSITIONER]

        def driver() -> bool:
            return alive() and self._alive[names.NODE_DRIVER]

        def send(traj: Trajectory, start: float | None = None) -> None:  # start: on receipt
            if driver():
                joints = np.hstack([traj.lengths, traj.thetas])
                rates = np.hstack([traj.length_rates, traj.theta_rates])
                with self._lock:
                    out = self.drives.follow(JOINT_NAMES, traj.times, joints, rates, None,
                                             time.monotonic(), '/' + names.NODE_POSITIONER)
                    self._answers.append(Answer(out.key, out.accepted, out.message))
                    self._report(time.monotonic(), out.message)

        def stop() -> None:
            if driver():
                with self._lock:
                    self.drives.stop(time.monotonic())

        def joints() -> JointReading | None:
            # read when the positioner looks (in a thread of the same process the drives'
            # timer may lag behind; the live driver publishes from a process of its own)
            if not driver():
                return None
            with self._lock:
                return self._advance(time.monotonic(), publish=True)

        def answers() -> list[Answer]:
            with self._lock:
                taken, self._answers = (self._answers, []) if driver() else ([], self._answers)
            return taken

        def reference() -> bool:
            if not driver():
                return False
            with self._lock:
                try:
                    self._report(time.monotonic(), self.drives.reference(time.monotonic()))
                except TrajectoryRefusedError as err:
                    self._report(time.monotonic(), str(err))
            return True

        def result(state: State, reason: str, code: ResultCode | None) -> None:
            if code is not None and alive():
                with self._lock:
                    self._results.append(Report(time.monotonic(), code.value, reason))

        return Machine(send_trajectory=send, stop_drives=stop,
                       publish_target=lambda p, q: None, latest_joints=joints,
                       new_measurements=lambda: self._measure() if alive() else [],
                       trajectory_answers=answers, reference_drives=reference,
                       drives_connected=driver, state_changed=result,
                       refused=lambda code, reason: result(State.IDLE, reason, code),
                       identity='/' + names.NODE_POSITIONER,
                       publisher_ids=lambda: frozenset({f'{generation:032x}'}))

    def _measure(self) -> list[Measurement]:
        """The tracker readings due since the last look (at its rate, with its faults)."""
        now = time.monotonic()
        period = 1.0 / self.sim.settings.rate_hz
        with self._lock:
            due = int((now - self._tracked) / period)
            if due < 1 or not self._alive[names.NODE_MEASUREMENT]:
                return []
            self._tracked += due * period
            p, q = self.cell.true_pose()
        due = min(due, 10)
        try:
            _, fit = observe(self.cell.instrument, self.cell.located, self.cell.targets,
                             np.repeat(p[None], due, 0), np.repeat(q[None], due, 0), self.rng,
                             self._faults, reject_threshold=self.sim.settings.fit.reject_threshold)
        except TooFewTargetsError:
            return []
        self._sigma = float(np.sqrt(np.max(np.diag(fit.covariance[-1])[:3])))
        return [Measurement(fit.position[k], fit.quaternion[k], fit.covariance[k])
                for k in range(due)]

    # -- the port -------------------------------------------------------------------------------
    @property
    def positioner_settings(self) -> PositionerSettings:
        return self._configured

    @property
    def heartbeat_timeout(self) -> float:
        return self._driver_settings.command.heartbeat_timeout

    def monotonic(self) -> float:
        return time.monotonic()

    def now(self) -> float:
        return time.monotonic()

    def rest(self, seconds: float) -> None:
        time.sleep(seconds)

    def joints(self) -> FloatArray:
        with self._lock:
            return self.drives.readings()[0].position.copy()

    def check(self, position: ArrayLike, quaternion: ArrayLike) -> Moved:
        try:
            self.mover.check(names.BASE_FRAME, position, quaternion)
        except MoveAbortedError as err:
            return Moved(False, err.code.value, str(err))
        return Moved(True, 'success', 'the goal can be reached')

    def set_parameter(self, node: str, name: str, value: ParameterValue) -> None:
        now = time.monotonic()
        if node == names.NODE_DRIVER:
            with self._lock:
                new = updated(self.drives.settings, name, value)
                self.drives.reconfigure(new, {name}, now)
        elif node == names.NODE_MEASUREMENT and name.startswith('fault.'):
            settings = updated(self.sim.settings, name, value)
            self.sim.settings, self._faults = settings, settings.fault
        elif node == names.NODE_POSITIONER:
            settings = updated(self.mover.settings, name, value)
            self.mover.prepare(settings)
            self.mover.reconfigure(settings)
        else:
            raise Unsupported(f'{node}.{name}: not a parameter of the cell in process')

    def enable_drives(self, on: bool) -> None:
        with self._lock:
            if self._alive[names.NODE_DRIVER]:
                self._report(time.monotonic(), self.drives.enable(on, time.monotonic()))

    def kill(self, node: str) -> None:
        if node not in NODES:
            raise Unsupported(f'{node}: not a node of the cell in process')
        with self._lock:
            self._alive[node] = False
            if node == names.NODE_POSITIONER:
                self._generation += 1

    def restart(self, node: str) -> None:
        if node not in NODES:
            raise Unsupported(f'{node}: not a node of the cell in process')
        now = time.monotonic()
        with self._lock:
            if node == names.NODE_DRIVER:
                self.drives = LegDriver(self._driver_settings, now)
            elif node == names.NODE_MEASUREMENT:
                self._tracked = now
            generation = self._generation
        if node == names.NODE_POSITIONER:
            self._start_positioner(self._configured, self._machine(generation))
        with self._lock:
            self._alive[node] = True

    def running(self, node: str) -> bool:
        return self._alive.get(node, False)

    def forgotten(self, node: str) -> bool:
        return True  # in process: nothing remembers a killed node

    def foreign_trajectory(self, joints: FloatArray, ahead: float,
                           timeout: float) -> tuple[float, Report]:
        now = time.monotonic()
        with self._lock:
            here = self.drives.servos.state.position.copy()
            positions = np.vstack([here, np.asarray(joints, float)])
            out = self.drives.follow(JOINT_NAMES, np.array([0.0, 20.0]), positions,
                                     np.zeros((2, 6)), now + ahead, now, '/' + CLIENT_NODE)
            self._report(now, out.message)
        return now, Report(time.monotonic(), out.code.value if out.code else 'accepted',
                           out.message)

    def spoof(self, topic: str, offset: float, messages: int, period: float) -> float:
        raise Unsupported('no second publisher in process: there is no topic')

    def flood(self, calls: int, bound: float) -> Flood:
        raise Unsupported('no flood of calls in process: there are no services')

    def result_after(self, since: float) -> Report | None:
        with self._lock:
            return next((r for r in self._results if r.time > since), None)

    def status_after(self, status: str, since: float, words: str) -> Report | None:
        if status != names.STATUS_DRIVER:
            raise Unsupported(f'no status {status!r} in process')
        with self._lock:
            return next((r for r in self._driver_reports
                         if r.time > since and words in r.message), None)

    def true_states(self, since: float) -> TrueStates:
        with self._lock:
            taken = [x for x in self._truth if x[0] > since]
        if not taken:
            return TrueStates.empty()
        return TrueStates(np.array([t for t, _, _ in taken]), np.array([p for _, p, _ in taken]),
                          np.array([v for _, _, v in taken]))

    def true_position_after(self, since: float) -> FloatArray | None:
        states = self.true_states(since)
        if not len(states.times):
            return None
        try:
            pose = self.cell.truth.poses(states.positions[:1, :3], states.positions[:1, 3:])
        except InputError:
            return None
        return np.asarray(pose.position[0])

    def estimates(self, since: float) -> FloatArray:
        with self._lock:
            return np.array([p for t, p in self._estimates if t > since]).reshape(-1, 3)

    def tracker_sigma(self) -> float:
        return self._sigma


__all__ = ['InstantFaultPort']
