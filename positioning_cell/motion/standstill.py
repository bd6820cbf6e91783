"""Standstill monitoring: while the positioner commands nothing, the axes and the platform must
stay where they came to rest (the drive-safety pattern of a monitored standstill, IEC 61800-5-2's
safe operating stop, done here by the commanding controller on its own sensors).

After every command that moved the axes the watch is re-armed (:meth:`StandstillWatch.arm`);
while a command runs the mover does not feed it. The encoders' rest position is taken at the
first reading with every axis slower than its rest speed; from then on the mean of the readings
of the last ``window`` s may not leave it by more than the tolerance of its axis. The tracker
is judged on its last ``TRACKER_READINGS`` readings once they agree (each within the tracker
tolerances of their medoid, the reading closest to the others): the first that agree after the
encoders came to rest give the rest pose (their medoid), later ones that agree may not leave it
by more than the tolerances. Readings that disagree among themselves are a tracker scattering
(outliers its fit kept, a disturbed line of sight), not a platform that moved: they are not
judged, so neither one stray reading nor a burst of them is motion, nor shifts the rest pose as
a mean would. A platform pushed through the joints' clearance comes to rest again and is then
found. Axes that do not come to rest within ``rest_timeout`` of the command's end are motion
too. Tracker readings stamped before the encoder reading the watch was armed at (on the
drives' clock the readings share) measured the platform while it still moved and are not
judged: a tracker that lags delivers them after the command ended. Positions in m and rad
(JOINT_NAMES order), poses in the base frame (m, unit quaternions x, y, z, w), times in s on
one monotonic clock.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.core.poses import as_pose_batch, pose_error
from positioning_cell.moves.correction import deviation
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]

#: Tracker readings that must agree to make the rest pose, and to be judged.
TRACKER_READINGS = 3


@dataclass(frozen=True)
class StandstillSettings:
    """The ``standstill:`` block of the positioner: how far the machine may move while nothing
    is commanded. The defaults sit above the encoders' and the tracker's noise (encoder noise
    0.2 µm / 2 µrad, 50 times that in a noise burst, averaged over ``window``; tracker σ a few
    µm) and far below a motion that matters to a panel."""

    length_tolerance: float = setting(50e-6, 'largest motion of a leg length at standstill '
                                      '(mean of the readings over window)', 'm', low=1e-7,
                                      high=0.01, dynamic=True)
    theta_tolerance: float = setting(5e-4, 'largest motion of a theta angle at standstill',
                                     'rad', low=1e-6, high=0.1, dynamic=True)
    tracker_position_tolerance: float = setting(
        100e-6, 'largest displacement of the measured platform at standstill (the last 3 '
        'tracker readings, when they agree within it)', 'm', low=1e-6, high=0.01, dynamic=True)
    tracker_orientation_tolerance: float = setting(
        5e-4, 'largest rotation of the measured platform at standstill', 'rad', low=1e-6,
        high=0.1, dynamic=True)
    window: float = setting(0.1, 'encoder readings averaged for the standstill check', 's',
                            low=0.0, high=1.0, dynamic=True)
    rest_timeout: float = setting(2.0, 'after a command ends, the axes must be at rest within '
                                  'this', 's', low=0.1, high=60.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def joint_tolerance(self) -> FloatArray:
        """Tolerance per axis (6,), m and rad."""
        return np.array([self.length_tolerance] * 3 + [self.theta_tolerance] * 3)


class Motion(NamedTuple):
    """Uncommanded motion found: the words for it (naming the axis or the tracker, how far,
    and the tolerance)."""

    reason: str


def _amount(axis: int, value: float) -> str:
    if axis < 3:
        return f'{value * 1e3:.3f} mm'
    return f'{math.degrees(value):.4f} deg'


class StandstillWatch:
    """The rule of the module docstring over the readings fed to it. Not thread-safe: the
    mover feeds it under its lock."""

    def __init__(self, settings: StandstillSettings) -> None:
        self.settings = settings
        self._armed_at: float | None = None
        self._armed_stamp = math.nan
        self._rest: FloatArray | None = None
        self._window: deque[tuple[float, FloatArray]] = deque()
        self._tracker_rest: tuple[FloatArray, FloatArray] | None = None
        self._tracker: deque[tuple[FloatArray, FloatArray]] = deque(maxlen=TRACKER_READINGS)

    @property
    def armed(self) -> bool:
        """The watch has been armed (it judges what it is fed)."""
        return self._armed_at is not None

    @property
    def at_rest(self) -> bool:
        """The encoders' rest position is known."""
        return self._rest is not None

    def arm(self, now: float, stamp: float = math.nan) -> None:
        """Motion ended (or the watch starts) at ``now``, ``stamp`` that of the newest encoder
        reading then (NaN: not known): watch from here, the rest positions taken anew."""
        self._armed_at, self._armed_stamp = now, float(stamp)
        self._rest, self._tracker_rest = None, None
        self._window.clear()
        self._tracker.clear()

    def joints(self, position: FloatArray, velocity: FloatArray, rest_speed: FloatArray,
               now: float) -> Motion | None:
        """An encoder reading (6,) m / rad with its velocity (6,) at ``now``; ``rest_speed``
        (6,) the speed below which an axis is at rest. Returns the motion it reveals."""
        if self._armed_at is None:
            return None
        s = self.settings
        if self._rest is None:
            if np.all(np.abs(velocity) <= rest_speed):
                self._rest = np.array(position, dtype=float)
                self._window.clear()
            elif now - self._armed_at > s.rest_timeout:
                axis = int(np.argmax(np.abs(velocity) / rest_speed))
                return Motion(f'uncommanded motion: {JOINT_NAMES[axis]} still moving '
                              f'{now - self._armed_at:.2f} s after the last command ended '
                              f'(rest_timeout {s.rest_timeout:g} s)')
            return None
        self._window.append((now, np.array(position, dtype=float)))
        while self._window and self._window[0][0] < now - s.window:
            self._window.popleft()
        moved = np.mean([p for _, p in self._window], axis=0) - self._rest
        excess = np.abs(moved) / s.joint_tolerance
        axis = int(np.argmax(excess))
        if excess[axis] <= 1.0:
            return None
        tolerance = float(s.joint_tolerance[axis])
        return Motion(f'uncommanded motion at standstill: {JOINT_NAMES[axis]} moved '
                      f'{_amount(axis, float(moved[axis]))} from where it came to rest '
                      f'(tolerance {_amount(axis, tolerance)})')

    def tracker(self, position: FloatArray, quaternion: FloatArray,
                stamp: float = math.nan) -> Motion | None:
        """A tracker reading of the platform (base frame) of the pose at ``stamp`` (NaN: not
        known). Returns the motion it reveals; the tracker is judged only once the encoders
        are at rest, on readings not stamped before the watch was armed."""
        if self._armed_at is None or self._rest is None or stamp < self._armed_stamp:
            return None
        self._tracker.append((np.array(position, dtype=float), np.array(quaternion, dtype=float)))
        if len(self._tracker) < TRACKER_READINGS:
            return None
        here = self._agreeing()
        if here is None:
            return None
        if self._tracker_rest is None:
            self._tracker_rest = here
            return None
        e_p, e_r = deviation(*here, *self._tracker_rest)
        s = self.settings
        if np.linalg.norm(e_p) > s.tracker_position_tolerance:
            return Motion(f'uncommanded motion at standstill: the tracker measures the platform '
                          f'{np.linalg.norm(e_p) * 1e3:.3f} mm from where it came to rest '
                          f'(tolerance {s.tracker_position_tolerance * 1e3:.3f} mm)')
        if np.linalg.norm(e_r) > s.tracker_orientation_tolerance:
            return Motion(f'uncommanded motion at standstill: the tracker measures the platform '
                          f'turned {math.degrees(float(np.linalg.norm(e_r))):.4f} deg from how '
                          f'it came to rest (tolerance '
                          f'{math.degrees(s.tracker_orientation_tolerance):.4f} deg)')
        return None

    def _agreeing(self) -> tuple[FloatArray, FloatArray] | None:
        """The medoid of the tracker readings held (the one whose summed distance to the
        others, position over tracker_position_tolerance plus rotation over
        tracker_orientation_tolerance, is least) when every reading is within the tolerances
        of it; None when they disagree."""
        s = self.settings
        readings = list(self._tracker)
        n = len(readings)
        p, q = as_pose_batch([r[0] for r in readings], [r[1] for r in readings])
        one, other = np.divmod(np.arange(n * n), n)  # every ordered pair, as one batch
        e_p, e_r = pose_error(p[one], q[one], p[other], q[other])
        scaled = np.stack([np.linalg.norm(e_p, axis=1) / s.tracker_position_tolerance,
                           np.linalg.norm(e_r, axis=1) / s.tracker_orientation_tolerance],
                          axis=1).reshape(n, n, 2)  # (reading, other, position/rotation)
        centre = int(np.argmin(scaled.sum(axis=(1, 2))))
        if np.any(scaled[centre] > 1.0):
            return None
        return readings[centre]
