"""How a command of the positioner ends: its state on /diagnostics, a result code naming the
outcome (success, a refusal, an abort, out of tolerance), the error that carries the code, and
the result of a settled move."""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import PositioningError

FloatArray = NDArray[np.float64]


class State(Enum):
    """States of the positioner, as reported on /diagnostics."""

    IDLE = 'idle'
    HOMING = 'homing'
    MOVING = 'moving'
    SETTLING = 'settling'
    CORRECTING = 'correcting'
    SETTLED = 'settled'
    ABORTED = 'aborted'
    FAULT = 'fault'


class ResultCode(Enum):
    """The outcome of a move or a check: refused (nothing moved), aborted (the drives were
    stopped), out of tolerance (settled, but not where asked), or success."""

    SUCCESS = 'success'
    REFUSED_INVALID_GOAL = 'refused_invalid_goal'
    REFUSED_LIMITS = 'refused_limits'
    REFUSED_NOT_REFERENCED = 'refused_not_referenced'
    REFUSED_DRIVES_OFF = 'refused_drives_off'
    REFUSED_DRIVE_FAULT = 'refused_drive_fault'
    REFUSED_DRIVER_SILENT = 'refused_driver_silent'
    REFUSED_BUSY = 'refused_busy'
    REFUSED_NO_ESTIMATE = 'refused_no_estimate'
    REFUSED_TRACKER_SILENT = 'refused_tracker_silent'
    REFUSED_NOT_COMMANDER = 'refused_not_commander'
    ABORTED_STOP = 'aborted_stop'
    ABORTED_FAULT = 'aborted_fault'
    ABORTED_DRIVES_OFF = 'aborted_drives_off'
    ABORTED_DRIVER_LOST = 'aborted_driver_lost'
    ABORTED_DRIVER_REFUSED = 'aborted_driver_refused'
    ABORTED_ENCODER = 'aborted_encoder'
    ABORTED_TRACKER_LOST = 'aborted_tracker_lost'
    ABORTED_TRACKER_INCONSISTENT = 'aborted_tracker_inconsistent'
    ABORTED_TIMEOUT = 'aborted_timeout'
    #: The coordinated cell: the positioners' disagreement loads the panel beyond its limit.
    ABORTED_INTERNAL_FORCE = 'aborted_internal_force'
    OUT_OF_TOLERANCE = 'out_of_tolerance'
    #: Not the end of a command: the machine moved while nothing was commanded (standstill
    #: monitoring); the drives were stopped.
    UNCOMMANDED_MOTION = 'uncommanded_motion'

    @property
    def refused(self) -> bool:
        """Nothing moved."""
        return self.value.startswith('refused')


#: Where an attained pose comes from: the laser tracker, or the encoders through the model.
MEASURED, ESTIMATED = 'measured', 'estimated'


class Attained(NamedTuple):
    """Where the platform is (or ended): position (3,) m and quaternion (4,) x, y, z, w in
    base, ``source`` :data:`MEASURED` or :data:`ESTIMATED`, and the pose's standard
    uncertainty (6,) (x, y, z m, rot-x, rot-y, rot-z rad; None: not known)."""

    position: FloatArray
    quaternion: FloatArray
    source: str
    uncertainty: FloatArray | None = None


class MoveAbortedError(PositioningError):
    """A move was refused or ended before it settled within its tolerance: ``code`` names
    the outcome, the message says why; ``attained``, where the platform ended when the move
    knew it (an out-of-tolerance move: the pose it was judged on), else None."""

    def __init__(self, code: ResultCode, message: str,
                 attained: Attained | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.attained = attained


class MoveResult(NamedTuple):
    """A settled move: the estimated poses while it ran, positions (M, 3) m and quaternions
    (M, 4); the words for how it ended; the attained error against the goal (Δp (3,) m and
    rotation vector (3,) rad: the tracker's in ``measured`` mode, else the encoders'); in
    ``measured`` mode its standard uncertainty (6,) (x, y, z m, rot-x, rot-y, rot-z rad; None
    otherwise); ``source``, what the error was measured with (:data:`MEASURED`,
    :data:`ESTIMATED`).
    """

    positions: FloatArray
    quaternions: FloatArray
    reason: str
    position_error: FloatArray
    orientation_error: FloatArray
    uncertainty: FloatArray | None = None
    source: str = ESTIMATED

    @property
    def path(self) -> tuple[FloatArray, FloatArray]:
        """The executed poses: positions (M, 3) m, quaternions (M, 4)."""
        return self.positions, self.quaternions

    @property
    def error_text(self) -> str:
        """|Δp| in µm and the angle in degrees."""
        return (f'{np.linalg.norm(self.position_error) * 1e6:.1f} um, '
                f'{np.degrees(np.linalg.norm(self.orientation_error)):.5f} deg')
