"""The cell as a fault trial sees it: :class:`FaultPort`, a
:class:`~positioning_cell.procedures.port.CellPort` that can also be hurt (a node's parameter
set, a node killed and started again, the drives switched off, a foreign message sent) and
watched (the positioner's results, the nodes' reports, the simulator's true joint states and
poses, each with its receipt time on :meth:`FaultPort.monotonic`). The trials and their judging
are :mod:`positioning_cell.procedures.fault_trials`; a port that cannot inject a kind of fault
raises :class:`Unsupported` (the in-process cell sends no DDS message, so it cannot be
spoofed or flooded). Joints (6,) in ``JOINT_NAMES`` order, m and rad; times in s."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.procedures.port import CellPort, FloatArray, Moved, ProcedureError

#: A parameter value a trial sets (the ROS parameter types it uses).
ParameterValue = bool | int | float | str | list[float]


class Unsupported(ProcedureError):  # noqa: N818 - what the port answers, not its failure
    """This port cannot inject that fault (the trial is for another port)."""


class Report(NamedTuple):
    """A status a node reported (or the positioner's result): its ``time`` s (of publication
    where the port knows it, else of receipt; the port's monotonic clock), the
    result ``code`` ('' when the status carries none) and its words."""

    time: float
    code: str
    message: str


class TrueStates(NamedTuple):
    """The simulator's true joint states received in a window: receipt times (k,) s,
    positions (k, 6) and velocities (k, 6)."""

    times: FloatArray
    positions: FloatArray
    velocities: FloatArray

    @classmethod
    def empty(cls) -> TrueStates:
        """No state."""
        return cls(np.empty(0), np.empty((0, 6)), np.empty((0, 6)))


class Flood(NamedTuple):
    """A flood of concurrent service calls: per service (its name) the calls made and the
    calls answered, and the time from the first call to the last answer (or to the bound)."""

    calls: dict[str, int]
    answered: dict[str, int]
    elapsed: float


class FaultPort(CellPort, Protocol):
    """A running cell the fault trials inject into and watch (module docstring). Nodes are
    named as in :mod:`positioning_cell.names` (``NODE_DRIVER``, ...); statuses by their
    /diagnostics names (``STATUS_POSITIONER``, ...)."""

    @property
    def positioner_settings(self) -> PositionerSettings:
        """The positioner's settings as configured at start (mechanism, tolerances, liveness,
        standstill)."""

    @property
    def heartbeat_timeout(self) -> float:
        """The leg driver's ``command.heartbeat_timeout`` as configured at start (s): how long
        it follows a trajectory after its commander's last heartbeat."""

    def monotonic(self) -> float:
        """The monotonic clock (s) the port stamps what it receives with."""

    def check(self, position: ArrayLike, quaternion: ArrayLike) -> Moved:
        """The positioner's check of a goal in ``base`` without moving (check_pose)."""

    # -- injections -----------------------------------------------------------------------------
    def set_parameter(self, node: str, name: str, value: ParameterValue) -> None:
        """Set a parameter of ``node`` (ProcedureError when it refuses; Unsupported when the
        port has no such parameter)."""

    def enable_drives(self, on: bool) -> None:
        """Switch the drives on (also clears a drive fault) or off."""

    def kill(self, node: str) -> None:
        """Kill ``node`` without clean-up (a crash)."""

    def restart(self, node: str) -> None:
        """Start ``node`` again after it was killed and wait until it answers."""

    def running(self, node: str) -> bool:
        """Is ``node`` running (not killed)?"""

    def forgotten(self, node: str) -> bool:
        """Has the rest of the cell forgotten a killed ``node`` (its DDS participant's lease
        run out, so a process started in its place is sent the others' data)?"""

    def foreign_trajectory(self, joints: FloatArray, ahead: float,
                           timeout: float) -> tuple[float, Report]:
        """From another node than the positioner (:data:`~.fault_trials.CLIENT_NODE`), once
        the driver has reported it as a foreign publisher: a trajectory from where the axes
        are to ``joints`` (6,) over 20 s, stamped ``ahead`` s ahead. The time it was sent and
        the driver's answer to it (its refusal code, or 'accepted')."""

    def spoof(self, topic: str, offset: float, messages: int, period: float) -> float:
        """A second publisher on ``topic`` (the encoders' or the tracker's) sends ``messages``
        readings ``offset`` m off the truth, one per ``period`` s; the clock time of the first
        (Unsupported in process)."""

    def flood(self, calls: int, bound: float) -> Flood:
        """``calls`` concurrent calls to every service of the cell at once, answers awaited
        up to ``bound`` s (Unsupported in process)."""

    # -- what the port saw ----------------------------------------------------------------------
    def result_after(self, since: float) -> Report | None:
        """The first result (a status of the positioner carrying a result code) received after
        ``since``."""

    def status_after(self, status: str, since: float, words: str) -> Report | None:
        """The first status named ``status`` received after ``since`` whose message has
        ``words``."""

    def true_states(self, since: float) -> TrueStates:
        """The true joint states received after ``since`` (judging only)."""

    def true_position_after(self, since: float) -> FloatArray | None:
        """The first true platform position (3,) m received after ``since`` (judging only)."""

    def estimates(self, since: float) -> FloatArray:
        """The positioner's pose estimates received after ``since``: positions (k, 3) m."""

    def tracker_sigma(self) -> float:
        """The tracker's stated position sigma (largest of x, y, z) of its latest reading, m
        (NaN: none yet)."""


__all__ = ['FaultPort', 'Flood', 'ParameterValue', 'ProcedureError', 'Report', 'TrueStates',
           'Unsupported']
