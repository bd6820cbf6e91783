"""The simulated laser tracker: the instrument as it really is (its true pose in the base
frame and its systematic errors, ``truth.tracker.*``), its noisy readings in its own frame, with
injected occlusions and outliers, and what the cell makes of them through its *located*
registration. Randomness only from the injected generator."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import Quad, Triple, as_pose_batch, as_unit_quaternions
from positioning_cell.errors import InputError
from positioning_cell.metrology.fit import DEFAULT_REJECT_THRESHOLD, PoseFit, fit_pose
from positioning_cell.metrology.instrument import Tracker, TrackerAccuracy, local_from_spherical
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Default true tracker pose: on its stand 2.2 m in front of the platform and 0.8 m aside,
#: levelled (its standing axis along base +y, against gravity) and turned towards the cell.
DEFAULT_TRACKER_POSITION: Triple = (0.8, 0.3, 2.2)
DEFAULT_TRACKER_ORIENTATION: Quad = (-0.675524910, 0.208964340, 0.208964340, 0.675524910)


@dataclass(frozen=True)
class TrackerTruth:
    """The ``truth.tracker:`` block (read-only): where the tracker really stands and its
    systematic errors, constant over a run, which averaging does not remove.

    position (m) and orientation (unit quaternion x, y, z, w) place the tracker frame in
    ``base``; scale_ppm: range scale error (the refractive index of air changes by about
    −0.95 ppm per K, so an air-temperature error of 2 K scales every range by ≈ 2 ppm);
    angle_offsets: constant azimuth and elevation errors (rad), e.g. a residual vertical index
    error of a few µrad, about half the angular slope of the transverse MPE (6 µm/m).
    """

    position: Triple = setting(DEFAULT_TRACKER_POSITION, 'true tracker origin, base frame', 'm')
    orientation: Quad = setting(DEFAULT_TRACKER_ORIENTATION, 'true tracker frame in base, '
                                'unit quaternion x, y, z, w')
    scale_ppm: float = setting(2.0, 'range scale error (air temperature)', 'ppm', low=-1000.0,
                               high=1000.0)
    angle_offsets: tuple[float, float] = setting((2e-6, -3e-6), 'constant azimuth, elevation '
                                                 'errors', 'rad', low=-0.01, high=0.01)

    def __post_init__(self) -> None:
        check_fields(self)
        try:
            as_unit_quaternions(self.orientation, 'orientation')
        except InputError as err:
            raise ParameterError('orientation', self.orientation,
                                 'must be a unit quaternion x, y, z, w') from err


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


# -- readings ----------------------------------------------------------------------------------
class Readings(NamedTuple):
    """Tracker readings: local (..., 3) m in the ``tracker`` frame, NaN where hidden; visible
    (...,); outlier (...,): the simulator's truth about which readings it corrupted."""

    local: FloatArray
    visible: BoolArray
    outlier: BoolArray


@dataclass(frozen=True)
class SimulatedTracker:
    """The real instrument: its ``truth`` (pose, systematic errors) and the random error of
    its datasheet ``accuracy``."""

    truth: TrackerTruth
    accuracy: TrackerAccuracy

    @cached_property
    def placed(self) -> Tracker:
        """The instrument at its true pose (truth: for the simulator and for judging)."""
        return Tracker(self.accuracy, self.truth.position, self.truth.orientation)

    def read(self, points: ArrayLike, rng: np.random.Generator,
             faults: TrackerFaults | None = None, *,
             refraction_ppm: ArrayLike = 0.0) -> Readings:
        """Readings of base-frame points (..., 3) m: the true (r, az, el), scaled by
        1 + (scale_ppm + refraction_ppm)·1e-6 (``refraction_ppm`` broadcast over the points'
        leading axes: the air temperature's error in the tracker's weather correction,
        :meth:`positioning_cell.sim.effects.thermal.Thermal.range_scale_ppm`) and offset by
        angle_offsets, plus independent normal noise of
        :meth:`TrackerAccuracy.reading_sigma`; then occlusion and outliers per ``faults``
        (an outlier displaced by outlier_magnitude in a random direction). The same number
        of draws is taken whatever the fault settings, so a seeded stream stays aligned."""
        faults = faults or TrackerFaults()
        true = self.placed.spherical(points)
        if np.any(true[..., 0] <= 0.0):
            raise InputError('a target coincides with the tracker position: no reading')
        az_offset, el_offset = self.truth.angle_offsets
        scale = 1.0 + (self.truth.scale_ppm + np.asarray(refraction_ppm, dtype=float)) * 1e-6
        biased = np.stack([true[..., 0] * scale, true[..., 1] + az_offset,
                           true[..., 2] + el_offset], axis=-1)
        noisy = biased + rng.standard_normal(true.shape) * self.accuracy.reading_sigma(true)
        local = local_from_spherical(noisy)
        shape = true.shape[:-1]
        hidden = rng.random(shape) < faults.occlusion_probability
        wild = (rng.random(shape) < faults.outlier_probability) & ~hidden
        direction = rng.standard_normal(true.shape)
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        local = np.where(wild[..., None], local + faults.outlier_magnitude * direction, local)
        local[hidden] = np.nan
        return Readings(local, ~hidden, wild)


class Measurement(NamedTuple):
    """Readings of the targets of N poses: points (N, T, 3) m in ``base`` as the cell has them
    (through its located registration), NaN where hidden; local (N, T, 3) m, the readings in
    the ``tracker`` frame; visible (N, T); outlier (N, T): the simulator's truth."""

    points: FloatArray
    local: FloatArray
    visible: BoolArray
    outlier: BoolArray


def measure(instrument: SimulatedTracker, located: Tracker, layout: TargetLayout,
            position: ArrayLike, quaternion: ArrayLike, rng: np.random.Generator,
            faults: TrackerFaults | None = None, *,
            refraction_ppm: ArrayLike = 0.0) -> Measurement:
    """Simulated readings of the targets of N true platform poses (N, 3) m, (N, 4) x, y, z, w
    (:meth:`SimulatedTracker.read`, ``refraction_ppm`` a number or one per pose (N,)),
    converted to ``base`` with the ``located`` registration (never the true pose: the cell
    knows only the one it located)."""
    p, q = as_pose_batch(position, quaternion)
    refraction = np.asarray(refraction_ppm, dtype=float)
    readings = instrument.read(layout.in_base(p, q), rng, faults,
                               refraction_ppm=refraction[:, None] if refraction.ndim == 1
                               else refraction)
    return Measurement(located.to_base(readings.local), readings.local, readings.visible,
                       readings.outlier)


def observe(instrument: SimulatedTracker, located: Tracker, layout: TargetLayout,
            position: ArrayLike, quaternion: ArrayLike, rng: np.random.Generator,
            faults: TrackerFaults | None = None, *,
            reject_threshold: float = DEFAULT_REJECT_THRESHOLD,
            refraction_ppm: ArrayLike = 0.0) -> tuple[Measurement, PoseFit]:
    """One tracker cycle for N true poses: :func:`measure` (``refraction_ppm`` passed on),
    then :func:`fit_pose` with the located registration."""
    measurement = measure(instrument, located, layout, position, quaternion, rng, faults,
                          refraction_ppm=refraction_ppm)
    return measurement, fit_pose(located, layout, measurement.points,
                                 reject_threshold=reject_threshold)
