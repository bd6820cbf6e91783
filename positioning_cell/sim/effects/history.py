"""The machine's state history the effects need: where each axis came from (the direction it
last moved in, for the reversal error) and how much each leg's screw travelled (its heating),
over time. :class:`Conditions` is that state at N samples; :func:`sequence_conditions` builds
it for a commanded sequence (offline), :class:`MachineHistory` follows a stream of true joint
states (the pose_measurement simulator)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE, Thermal

FloatArray = NDArray[np.float64]

#: A motion against the current direction smaller than this (m ×3, rad ×3) is servo dither,
#: not a reversal (the true joint stream of the leg driver settles within it).
REVERSAL_THRESHOLD = np.r_[[1e-7] * 3, [1e-6] * 3]


class Conditions(NamedTuple):
    """The true state of the machine at N samples: ``air`` (N,) °C, ``legs`` (N, 3) °C the
    legs' temperatures, ``approach`` (N, 6) the direction each axis last moved in (±1, 0:
    unknown), joint order of the encoders."""

    air: FloatArray
    legs: FloatArray
    approach: FloatArray

    @classmethod
    def reference(cls, n: int) -> Conditions:
        """N samples at 20 °C, approach unknown (the effects' neutral state)."""
        return cls(np.full(n, REFERENCE_TEMPERATURE), np.full((n, 3), REFERENCE_TEMPERATURE),
                   np.zeros((n, 6)))


def approach_directions(commands: ArrayLike) -> FloatArray:
    """The direction (N, 6) ±1 each axis of a commanded sequence (N, 6) last moved in before
    reaching each row: the sign of its last non-zero change (0: none yet)."""
    cmd = np.atleast_2d(np.asarray(commands, dtype=float))
    step = np.sign(np.diff(cmd, axis=0, prepend=cmd[:1]))
    rows = np.where(step != 0.0, np.arange(cmd.shape[0])[:, None], -1)
    last = np.maximum.accumulate(rows, axis=0)
    out: FloatArray = np.where(last >= 0, np.take_along_axis(step, np.maximum(last, 0), axis=0),
                               0.0)
    return out


def sequence_conditions(thermal: Thermal | None, commands: ArrayLike,
                        times: ArrayLike) -> Conditions:
    """The conditions at each pose of a commanded sequence (N, 6) (lengths m, θ rad) reached
    at times (N,) s since the start: approach from the sequence, the legs heated by the
    travel between poses (None: no thermal effects, 20 °C)."""
    cmd = np.atleast_2d(np.asarray(commands, dtype=float))
    t = np.asarray(times, dtype=float)
    approach = approach_directions(cmd)
    if thermal is None:
        return Conditions.reference(cmd.shape[0])._replace(approach=approach)
    travel = np.abs(np.diff(cmd[:, :3], axis=0, prepend=cmd[:1, :3]))
    air = thermal.air(t)
    excess = thermal.heating(np.zeros(3), float(t[0]) if t.size else 0.0, t, travel)
    return Conditions(air, air[:, None] + excess, approach)


class MachineHistory:
    """The history of a stream of true joint states (6,) at times s since the start: where
    each axis sits in its reversal band and the legs' heating.

    With the drives' reversal ``bands`` (6,) m, rad (full widths) the band is a play
    (backlash) operator: the real axis follows the motor only once the motor has taken up the
    play, real = motor − lag with lag = clip(motor − real_before, −band/2, +band/2); the
    approach is lag / (band/2) in [−1, 1] (±1 after a move longer than the band, anything
    between after a shorter reversal; servo dither within the band moves nothing). Without
    bands, the approach is the sign of the last motion (a reversal counting once the axis has
    moved back by more than :data:`REVERSAL_THRESHOLD` from its furthest point)."""

    def __init__(self, thermal: Thermal | None, bands: ArrayLike | None = None) -> None:
        self.thermal = thermal
        self._half = None if bands is None else 0.5 * np.asarray(bands, dtype=float)
        self._real: FloatArray | None = None
        self._anchor: FloatArray | None = None
        self._previous = np.zeros(6)
        self.approach = np.zeros(6)
        self._excess = np.zeros(3)
        self._time = 0.0

    def update(self, joints: ArrayLike, time: float) -> None:
        """The axes stand at ``joints`` (6,) m, rad at ``time`` s (not before the last)."""
        x = np.asarray(joints, dtype=float)
        if self._anchor is None:
            self._anchor, self._previous, self._time = x.copy(), x.copy(), time
            self._real = x.copy()
            return
        if self._half is not None and self._real is not None:
            lag = np.clip(x - self._real, -self._half, self._half)
            self._real = x - lag
            self.approach = np.divide(lag, self._half, out=np.zeros(6), where=self._half > 0)
            onward = turned = np.zeros(6, dtype=bool)
        else:
            delta = x - self._anchor
            onward = delta * self.approach > 0.0
            turned = (np.abs(delta) > REVERSAL_THRESHOLD) & (np.sign(delta) != self.approach)
            self.approach = np.where(turned, np.sign(delta), self.approach)
        travel = np.abs(x[:3] - self._previous[:3])
        self._previous = x.copy()
        self._anchor = np.where(onward | turned, x, self._anchor)
        if self.thermal is not None:
            self._excess = self.thermal.heating(self._excess, self._time, np.array([time]),
                                                travel[None])[0]
            self._time = time

    def conditions(self, time: float) -> Conditions:
        """The conditions (one sample) at ``time`` s."""
        if self.thermal is None:
            return Conditions.reference(1)._replace(approach=self.approach[None].copy())
        air = self.thermal.air(np.array([time]))
        decay = np.exp(-(time - self._time) / self.thermal.parameters.time_constant)
        return Conditions(air, air[:, None] + self._excess[None] * decay,
                          self.approach[None].copy())
