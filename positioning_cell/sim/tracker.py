"""The simulated laser tracker: noisy readings of the platform's targets at the true pose, with
injected occlusions and outliers, and the fit the real instrument's software would make of
them. Randomness only from the injected generator."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.metrology.fit import DEFAULT_REJECT_THRESHOLD, PoseFit, fit_pose
from positioning_cell.metrology.instrument import Tracker
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class TrackerFaults:
    """Simulated measurement faults, independent per target and reading: a target is hidden
    (line of sight blocked) with occlusion_probability; a visible reading is an outlier with
    outlier_probability: its point is displaced by outlier_magnitude (m) in a random direction
    (a mis-seated SMR, a beam re-acquired on a wrong reflector)."""

    occlusion_probability: float = setting(0.0, 'chance a target is hidden, per target and '
                                           'reading', low=0.0, high=1.0, dynamic=True)
    outlier_probability: float = setting(0.0, 'chance a visible reading is an outlier',
                                         low=0.0, high=1.0, dynamic=True)
    outlier_magnitude: float = setting(1e-3, 'outlier displacement', 'm', low=0.0, high=0.1,
                                       dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


# -- measurement -------------------------------------------------------------------------------
class Measurement(NamedTuple):
    """Readings of N poses: points (N, T, 3) m in ``base``, NaN where hidden; visible (N, T);
    outlier (N, T): the simulator's truth about which readings it corrupted."""

    points: FloatArray
    visible: BoolArray
    outlier: BoolArray

def measure(tracker: Tracker, layout: TargetLayout, position: ArrayLike, quaternion: ArrayLike,
            rng: np.random.Generator, faults: TrackerFaults | None = None) -> Measurement:
    """Simulated readings of the targets of N platform poses (N, 3) m, (N, 4) x, y, z, w.

    Each visible target's reading (r, az, el) gets independent normal noise of
    :meth:`Tracker.reading_sigma`; then occlusion and outliers per ``faults``. The same number
    of draws is taken whatever the fault settings, so a seeded stream stays aligned.
    """
    faults = faults or TrackerFaults()
    p, q = as_pose_batch(position, quaternion)
    true_points = layout.in_base(p, q)
    readings = tracker.spherical(true_points)
    if np.any(readings[..., 0] <= 0.0):
        raise InputError('a target coincides with the tracker position: no reading')
    noisy = readings + rng.standard_normal(readings.shape) * tracker.reading_sigma(readings)
    points = tracker.points(noisy)
    shape = readings.shape[:-1]
    hidden = rng.random(shape) < faults.occlusion_probability
    wild = (rng.random(shape) < faults.outlier_probability) & ~hidden
    direction = rng.standard_normal(readings.shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    points = np.where(wild[..., None], points + faults.outlier_magnitude * direction, points)
    points[hidden] = np.nan
    return Measurement(points, ~hidden, wild)

def observe(tracker: Tracker, layout: TargetLayout, position: ArrayLike, quaternion: ArrayLike,
            rng: np.random.Generator, faults: TrackerFaults | None = None, *,
            reject_threshold: float = DEFAULT_REJECT_THRESHOLD) -> tuple[Measurement, PoseFit]:
    """One tracker cycle for N true poses: :func:`measure`, then :func:`fit_pose`."""
    measurement = measure(tracker, layout, position, quaternion, rng, faults)
    return measurement, fit_pose(tracker, layout, measurement.points,
                                 reject_threshold=reject_threshold)
