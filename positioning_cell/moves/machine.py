"""The machine as the positioner's mover sees it (:mod:`positioning_cell.motion.mover`): what
it commands (a trajectory, a stop, the announced target) and what it reads (encoder readings,
tracker measurements, the drives' answers), as a set of callables, so that the ROS node, an
in-process simulated cell (:mod:`positioning_cell.sim.instant_cell`) and the unit tests give the
mover the same world. Poses in ``base``: m, unit quaternions x, y, z, w; joints in JOINT_NAMES
order."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.metrology.instrument import Registration
from positioning_cell.moves.outcomes import ResultCode, State

if TYPE_CHECKING:  # an annotation only: the planner stays out of the nodes that do not plan
    from positioning_cell.moves.trajectory import Trajectory

FloatArray = NDArray[np.float64]


class JointReading(NamedTuple):
    """Encoder readings: position (6,) m / rad, velocity (6,) m/s / rad/s, and when the
    drives took them (s on the cell's clock, the message stamp; NaN: not known)."""

    position: FloatArray
    velocity: FloatArray
    stamp: float = math.nan


class Measurement(NamedTuple):
    """A tracker reading of the platform: position (3,) m, quaternion (4,), covariance (6, 6)
    (x, y, z, rot-x, rot-y, rot-z; m², rad²), and the time of the pose it measured (s on the
    clock of :attr:`JointReading.stamp`; NaN: not known)."""

    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    stamp: float = math.nan


class Answer(NamedTuple):
    """The drives' answer to a trajectory: its key (:func:`fingerprint`), accepted or not, and
    the words."""

    key: str
    accepted: bool
    reason: str


def _nothing(*_: object) -> None:
    """A report nobody listens to."""


@dataclass(frozen=True)
class Machine:
    """What the mover does to and reads from the world.

    ``send_trajectory(traj, start)`` commands the drives (``start``: ROS time s at which they
    start it, the trajectory's header stamp; None: on receipt); ``wall_clock()`` is ROS time
    in s (what a start is given in); ``stop_drives()`` sends the controlled stop;
    ``publish_target(p, q)`` announces the goal; ``latest_joints()`` gives the newest encoder
    reading since the last call (None: nothing new); ``new_measurements()`` the tracker
    readings and ``trajectory_answers()`` the drives' answers that came in since the last call,
    oldest first; ``reference_drives()`` asks the drives to reference (False: they cannot be
    asked, nothing was sent); ``drives_connected()`` says whether the drives are there to take
    a trajectory and answer it (a driver that was just restarted is not, until discovery has
    matched both ways); ``state_changed(state, reason, code)`` reports a new state,
    ``refused(code, reason)`` a refusal (the state stays); ``clock()`` is a monotonic clock
    in s; ``identity`` the name the drives must take commands from (the positioner node's fully
    qualified name; '' when not checked); ``publisher_ids()`` the GIDs (hex) of the positioner's
    trajectory publisher, which the drives' status must list before a command is sent (empty:
    not checked); ``registration()`` the tracker's registration published
    since the last call (None: nothing new; with none ever received the mover splits the
    readings' stated covariance by their scatter,
    :func:`~positioning_cell.moves.correction.mean_reading`).
    """

    send_trajectory: Callable[[Trajectory, float | None], None]
    stop_drives: Callable[[], None]
    publish_target: Callable[[FloatArray, FloatArray], None]
    latest_joints: Callable[[], JointReading | None]
    new_measurements: Callable[[], list[Measurement]]
    trajectory_answers: Callable[[], list[Answer]]
    reference_drives: Callable[[], bool] = lambda: True
    drives_connected: Callable[[], bool] = lambda: True
    state_changed: Callable[[State, str, ResultCode | None], None] = field(default=_nothing)
    refused: Callable[[ResultCode, str], None] = field(default=_nothing)
    clock: Callable[[], float] = time.monotonic
    wall_clock: Callable[[], float] = time.time
    identity: str = ''
    publisher_ids: Callable[[], frozenset[str]] = frozenset
    registration: Callable[[], Registration | None] = lambda: None


