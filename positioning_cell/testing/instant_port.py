"""The in-process port: :class:`~positioning_cell.procedures.port.CellPort` on the positioner's
own move logic (:class:`~positioning_cell.motion.mover.Mover` and its operator surface
:class:`~positioning_cell.motion.controller.Controller`, unchanged) driving an
:class:`~positioning_cell.sim.instant_cell.InstantCell` (drives that arrive at once, encoders
that read the axes exactly, the simulated tracker), on a virtual clock. Every procedure runs on
it in a unit test in seconds, without DDS. The truth stays in the simulator: the port gives
it out only as the "true" axis positions of :class:`~positioning_cell.procedures.port.Readings`
(judging only), as the live simulator does on ``/sim/legs/true_joint_states``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell import names
from positioning_cell.accuracy.verdicts import Tolerances, judge_poses
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.errors import ConfigError, InputError, PositioningError
from positioning_cell.motion.controller import Controller, MoveCommand
from positioning_cell.motion.mover import Mover
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.moves.correction import mean_reading
from positioning_cell.moves.machine import Machine
from positioning_cell.moves.outcomes import MoveAbortedError
from positioning_cell.parameters import parse
from positioning_cell.procedures.port import FloatArray, Moved, ProcedureError, Readings, Seen
from positioning_cell.sim.instant_cell import DRIVES_READY, InstantCell
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator
from positioning_cell.sim.tracker import observe

#: The longest encoder freeze window the positioner accepts (s): ``liveness.freeze_window``.
FREEZE_WINDOW_MAX = 10.0
#: The simulated tracker's reading rate (Hz): the virtual time a window of readings takes.
TRACKER_RATE_HZ = 20.0


def _moved(action: object) -> Moved:
    """A finished command as :class:`Moved` (the mover raises MoveAbortedError otherwise)."""
    return Moved(True, 'success', str(getattr(action, 'reason', 'done')))


def _since(log: list[tuple[float, Any]], since: float,
           shape: tuple[int, ...]) -> tuple[FloatArray, FloatArray]:
    """The entries of a (stamp, value) log stamped from ``since`` on: stamps (M,) ascending
    (equal stamps in the log's order) and values (M, *shape)."""
    stamps = np.array([t for t, _ in log], dtype=float)
    keep = np.flatnonzero(stamps >= since)
    keep = keep[np.argsort(stamps[keep], kind='stable')]
    values = np.array([log[k][1] for k in keep], dtype=float).reshape(-1, *shape)
    return stamps[keep], values


class InstantPort:
    """The procedures' cell in process (module docstring): the machine of the simulator
    ``sim`` (located), driven by a mover with ``settings`` (its settle time should be 0: the
    drives arrive at once), coordinate systems in ``folder``; ``seed`` draws the tracker's
    noise."""

    def __init__(self, sim: PoseMeasurementSimulator, settings: PositionerSettings,
                 folder: Path, seed: int = 2) -> None:
        if sim.location is None:
            raise ProcedureError('the simulated tracker has not located itself')
        self.sim = sim
        self.cell = InstantCell(sim.truth, sim.instrument, sim.location.tracker,
                                sim.settings.targets, np.random.default_rng(seed))
        self._systems = folder / 'systems.yaml'
        self._start_positioner(settings, self.cell.machine())
        self.mover.driver_status(DRIVES_READY)
        if self.mover.estimate_pose() is None:  # takes the first encoder reading
            raise ProcedureError('the simulated cell gives no pose estimate')
        self.rng = np.random.default_rng(seed + 1)
        self.clock = 0.0
        self.tolerances = Tolerances()
        #: What the procedure sent: (topic, text) per marker, in order.
        self.marks: list[tuple[str, str]] = []
        #: Every command, in order: ('home' | 'move' | 'jog', what, Moved).
        self.commands: list[tuple[str, object, Moved]] = []
        self.stops = 0
        self._verdicts: list[str] = []
        self._goal: tuple[FloatArray, FloatArray] | None = None
        #: The encoder stream: a reading after every command and at every window's start.
        self._encoders: list[tuple[float, FloatArray]] = []
        #: The air-temperature sensor's readings, at its rate on the port's clock.
        self._air: list[tuple[float, float]] = []
        self._air_next: float | None = None
        self._air_period = 1.0 / sim.settings.air_sensor.rate_hz

    @classmethod
    def from_config(cls, folder: Path, config: Path | None = None, *, seed: int = 2,
                    sim_settings: PoseMeasurementSettings | None = None) -> InstantPort:
        """The cell of a parameter file (default: the shipped ``config/cell.yaml``): its
        simulator (or ``sim_settings``) and its positioner, settle time 0 and the encoder
        freeze rule at its longest window: the rule runs on the wall clock, and on a loaded
        machine a pause of the procedure's thread between an instant move's steps would look
        like a frozen encoder (the fault trials keep the rule: :mod:`.instant_faults`)."""
        params = load_parameter_file(config or config_path())
        if sim_settings is None:
            sim_settings = parse(PoseMeasurementSettings,
                                 node_parameters(params, names.NODE_MEASUREMENT))
        positioner = parse(PositionerSettings, node_parameters(params, names.NODE_POSITIONER))
        positioner = replace(positioner, settle_time=0.0, liveness=replace(
            positioner.liveness, freeze_window=FREEZE_WINDOW_MAX))
        return cls(PoseMeasurementSimulator(sim_settings), positioner, folder, seed)

    def _start_positioner(self, settings: PositionerSettings, machine: Machine) -> None:
        """A positioner (:attr:`mover` and its :attr:`controller`) with ``settings`` on
        ``machine``: at start, and again when a port starts it anew."""
        self.mover = Mover(settings, machine)
        self.controller = Controller(self.mover, replace(
            settings.operator, coordinate_systems_file=str(self._systems)))

    def now(self) -> float:
        return self.clock

    # -- moves ----------------------------------------------------------------------------------
    def _run(self, kind: str, what: object, command: object) -> Moved:
        try:
            moved = _moved(command() if callable(command) else command)
        except MoveAbortedError as err:
            moved = Moved(False, err.code.value, str(err))
        self.commands.append((kind, what, moved))
        self._encoders.append((self.now(), self.joints()))
        return moved

    def home(self) -> Moved:
        mech = self.mover.mech
        self._goal = (np.asarray(mech.home_position, float),
                      np.asarray(mech.home_quaternion, float))
        return self._run('home', None, self.mover.home)

    def move(self, position: ArrayLike, quaternion: ArrayLike, tolerance: float = 0.0) -> Moved:
        p = np.asarray(position, dtype=float)
        q = np.asarray(quaternion, dtype=float)
        self._goal = (p, q)
        command = MoveCommand('absolute', names.BASE_FRAME, p, q, float(tolerance))
        return self._run('move', (p, q), lambda: self.controller.move(command))

    def jog(self, axis: str, delta: float) -> Moved:
        self._goal = None
        return self._run('jog', (axis, delta), lambda: self.controller.jog(axis, delta))

    def stop(self) -> None:
        self.stops += 1
        self.mover.stop()

    def rest(self, seconds: float) -> None:
        self.clock += seconds

    # -- settings -------------------------------------------------------------------------------
    def _reconfigure(self, settings: PositionerSettings) -> None:
        self.mover.prepare(settings)
        self.mover.reconfigure(settings)

    def mode(self) -> str:
        return str(self.mover.settings.compensation.mode)

    def set_mode(self, mode: str) -> None:
        s = self.mover.settings
        try:
            self._reconfigure(replace(s, compensation=replace(s.compensation, mode=mode)))
        except (ConfigError, PositioningError, ValueError) as err:
            raise ProcedureError(f'the positioner refused compensation.mode = {mode}: '
                                 f'{err}') from err

    def calibration_file(self) -> str:
        return str(self.mover.settings.compensation.calibration_file)

    def load_calibration(self, path: str) -> tuple[bool, str]:
        s = self.mover.settings
        try:
            self._reconfigure(replace(s, compensation=replace(s.compensation,
                                                              calibration_file=path)))
        except (ConfigError, PositioningError) as err:
            return False, str(err)
        return True, ''

    # -- readings -------------------------------------------------------------------------------
    def joints(self) -> FloatArray:
        return self.cell.position.copy()

    def readings(self, samples: int, timeout: float) -> Readings:
        p, q = self.cell.true_pose()
        _, fit = observe(self.cell.instrument, self.cell.located, self.cell.targets,
                         np.repeat(p[None], samples, 0), np.repeat(q[None], samples, 0),
                         self.rng)
        start = self.clock
        self._encoders.append((start, self.joints()))
        stamps = start + np.arange(samples) / TRACKER_RATE_HZ
        self.clock = start + samples / TRACKER_RATE_HZ
        self._sense_air()
        # the encoders read the axes exactly here: the truth is where they stand
        return Readings(stamps, fit.position, fit.quaternion, fit.covariance,
                        self.cell.position.copy(), self.cell.position.copy(), start,
                        float(stamps[-1]), None, self.cell.located.registration)

    def encoder_stream(self, since: float) -> tuple[FloatArray, FloatArray]:
        return _since(self._encoders, since, (6,))

    def _sense_air(self) -> None:
        """The sensor's readings due on the port's clock since the last (at its rate; the
        first now)."""
        now = self.now()
        first = now if self._air_next is None else self._air_next
        stamps = np.arange(first, now + 1e-9, self._air_period)
        values = self.cell.air_readings(stamps.size)
        self._air.extend(zip(stamps.tolist(), values.tolist(), strict=True))
        self._air_next = first + stamps.size * self._air_period

    def air_temperature(self, since: float) -> tuple[FloatArray, FloatArray]:
        self._sense_air()
        stamps, values = _since(self._air, since, ())
        return stamps, values

    def apply_load(self, force: ArrayLike) -> None:
        try:
            self.sim.apply_load(force)
        except InputError as err:
            raise ProcedureError(str(err)) from err
        self.cell.truth = self.sim.truth  # the machine under its new load

    # -- markers and the monitor ----------------------------------------------------------------
    def mark(self, topic: str, text: str) -> None:
        if topic not in names.MARKER_TOPICS:
            raise ValueError(f'{topic} is not a marker topic ({", ".join(names.MARKER_TOPICS)})')
        self.marks.append((topic, text))

    def recorded(self, topic: str) -> bool:
        return False  # no recorder in process

    def seen(self) -> Seen:
        return Seen(len(self._verdicts), None)

    def verdict(self, before: Seen, timeout: float) -> str | None:
        """The monitor's rule on the pose the last move settled at: the mean of ten tracker
        readings against its goal (None after a jog or before any move)."""
        if self._goal is None:
            return None
        r = self.readings(10, timeout)
        p, q, cov = mean_reading(r.position, r.quaternion, r.covariance)
        verdict = judge_poses(p[None], q[None], self._goal[0][None], self._goal[1][None],
                              self.tolerances, cov[None])[0]
        self._verdicts.append(verdict.short())
        return self._verdicts[before.verdicts] if len(self._verdicts) > before.verdicts else None
