"""The cell as a procedure sees it: :class:`CellPort`, the few things every procedure asks of
a running cell, and the types they answer with. Poses in ``base``: positions (3,) m, unit
quaternions (4,) x, y, z, w; joints (6,) in ``JOINT_NAMES`` order, m and rad; times in s on
the cell's clock (:meth:`CellPort.now`)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import PositioningError
from positioning_cell.metrology.instrument import Registration

FloatArray = NDArray[np.float64]
#: A line of progress for the person running the procedure.
Say = Callable[[str], None]


class ProcedureError(PositioningError):
    """The cell refused or did not complete a step of a procedure (the reason; ``code``: the
    positioner's result code when it gave one, e.g. ``refused_busy``)."""

    def __init__(self, message: str, code: str = '') -> None:
        super().__init__(message)
        self.code = code


class Moved(NamedTuple):
    """How a commanded move (a goal, a homing, a jog) ended: ``success`` (settled within its
    tolerance), the positioner's result code name (``success``, ``refused_*``, ``aborted_*``,
    ``out_of_tolerance``; '' when no answer came) and its words."""

    success: bool
    code: str
    reason: str


class Readings(NamedTuple):
    """What the cell read over a window: the tracker readings' stamps (k,) s, positions (k, 3)
    m, quaternions (k, 4) and covariances (k, 6, 6) (x, y, z, rot-x, rot-y, rot-z; m², rad²);
    the mean encoder values (6,) over the window; the mean true axis positions (6,) (judging
    only, a simulated cell; else None); the window ``start`` … ``end`` s; the standard error
    of the mean encoder values (6,) (std / √n over the window; None: not known, e.g. one
    exact reading); the tracker's published registration the readings were taken through
    (its covariance at the readings' mean position is the part of every reading's covariance
    common to all of them; None: none received)."""

    stamps: FloatArray
    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    encoder: FloatArray
    true: FloatArray | None
    start: float
    end: float
    encoder_sem: FloatArray | None = None
    registration: Registration | None = None


class Seen(NamedTuple):
    """What the accuracy monitor had seen before a move: its verdicts so far and, judging a
    simulated cell only, the settled visits of the true pose (None: no truth)."""

    verdicts: int
    true_visits: int | None


class CellPort(Protocol):
    """A running cell, as the procedures drive it. Every method may be called from the
    procedure's thread; :meth:`stop` from any thread."""

    def now(self) -> float:
        """The cell's clock, s."""

    def home(self) -> Moved:
        """Reference the drives if needed and move to the home pose."""

    def move(self, position: ArrayLike, quaternion: ArrayLike, tolerance: float = 0.0) -> Moved:
        """Move to an absolute goal in ``base`` and settle (``tolerance`` m; 0: the
        positioner's own)."""

    def jog(self, axis: str, delta: float) -> Moved:
        """Move axis ``axis`` by ``delta`` (m or rad, within the largest jog step), outside the
        kinematics."""

    def mode(self) -> str:
        """The positioner's compensation mode (none, model, measured)."""

    def set_mode(self, mode: str) -> None:
        """Set the compensation mode (ProcedureError, with the positioner's reason, when it
        refuses)."""

    def calibration_file(self) -> str:
        """The calibration file the positioner has loaded ('' when none)."""

    def load_calibration(self, path: str) -> tuple[bool, str]:
        """Ask the positioner to load the calibration file ``path``: (taken, its reason)."""

    def joints(self) -> FloatArray:
        """The encoders now (6,): a reading taken at or after the call, never one from
        before it (ProcedureError when none comes)."""

    def readings(self, samples: int, timeout: float) -> Readings:
        """The next ``samples`` tracker readings stamped from now on, with the encoder (and,
        simulated, true) values over the same window (ProcedureError naming what did not
        come within ``timeout`` s)."""

    def encoder_stream(self, since: float) -> tuple[FloatArray, FloatArray]:
        """The encoder readings stamped from ``since`` s on, as far as the port still holds
        them (at least the last 30 s): stamps (M,) s ascending and values (M, 6)."""

    def air_temperature(self, since: float) -> tuple[FloatArray, FloatArray]:
        """The air-temperature sensor's readings (/cell/air_temperature: the reading, not the
        true air) stamped from ``since`` s on: stamps (K,) s ascending and values (K,) °C
        (empty: none came)."""

    def apply_load(self, force: ArrayLike) -> None:
        """Have the load rig push the platform origin with ``force`` (3,) N, base frame
        (zeros: unloaded); returns once the rig's load cell reads it (ProcedureError naming
        what went wrong: the rig refused it, or did not report it in time)."""

    def mark(self, topic: str, text: str) -> None:
        """Send a marker (JSON text) on one of the cell's marker topics
        (:data:`positioning_cell.names.MARKER_TOPICS`), kept for a recorder that joins late."""

    def recorded(self, topic: str) -> bool:
        """Does a recorder take ``topic``?"""

    def seen(self) -> Seen:
        """What the accuracy monitor has seen so far (taken before a move, to wait for the
        verdict on it)."""

    def verdict(self, before: Seen, timeout: float) -> str | None:
        """The monitor's verdict (a few words) on the first pose settled after ``before``,
        once it (and the true pose, when judged) has settled (None: none within ``timeout``
        s)."""

    def stop(self) -> None:
        """Stop the drives now (the move running ends, aborted)."""

    def rest(self, seconds: float) -> None:
        """Let ``seconds`` pass with the axes at rest."""


def moved_or_raise(moved: Moved, what: str) -> None:
    """ProcedureError naming ``what`` and the outcome when ``moved`` did not succeed."""
    if not moved.success:
        raise ProcedureError(f'{what}: {moved.code or "no answer"}: {moved.reason}', moved.code)


@contextmanager
def in_mode(port: CellPort, mode: str, what: str, say: Say,
            refused: type[ProcedureError] = ProcedureError) -> Iterator[None]:
    """The block run with the positioner in compensation ``mode`` (its refusal raised as
    ``refused``, nothing run), then the previous mode put back (a refusal then said, naming
    ``what``). The drives are stopped when anything but the cell's refusal or abort (a
    ProcedureError: an interrupt, say) ends the block."""
    previous = port.mode()
    try:
        port.set_mode(mode)
    except ProcedureError as err:
        raise refused(str(err)) from err
    try:
        yield
    except ProcedureError:
        raise
    except BaseException:
        port.stop()
        raise
    finally:
        try:
            port.set_mode(previous)
        except ProcedureError as err:
            say(f'{what}: the mode was not put back: {err}')


def say_recorded(port: CellPort, topic: str, say: Say) -> None:
    """Say whether a recorder took the markers of ``topic``."""
    say(f'the recorder took the markers ({topic})' if port.recorded(topic)
        else f'no recorder took the markers ({topic}): not in a bag')


def as_pose(position: ArrayLike, quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A goal as float arrays (3,) and (4,)."""
    return (np.asarray(position, dtype=float).reshape(3),
            np.asarray(quaternion, dtype=float).reshape(4))
