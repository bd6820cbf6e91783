"""The validity envelope of a calibration: the conditions it was identified over. A model fitted
to data is only tested where the data are; outside, it extrapolates (the load model to another
payload, the thermal terms to another temperature, the geometry to poses beyond the measured
ones). The envelope is the payload mass range, the measured temperature range, the convex hull
of the measured positions (base frame) and the largest rotation from the home orientation;
:meth:`Envelope.reasons` says why a pose or a condition lies outside it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import (
    as_pose_batch,
    as_unit_quaternions,
    quaternion_inverse,
    quaternion_product,
    rotation_angle,
)
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: How far outside the measured positions' hull a position is still inside (m): the tracker's
#: and the hull's own resolution, not an extrapolation.
HULL_MARGIN = 1e-4
#: How much beyond the largest measured rotation still counts as inside (rad).
ROTATION_MARGIN = 1e-3


def rotation_from_home(mech: Mechanism, quaternion: ArrayLike) -> FloatArray:
    """The angle (N,) rad of each orientation (N, 4) from the home orientation."""
    home = as_unit_quaternions(mech.home_quaternion, 'home_quaternion')
    return rotation_angle(quaternion_product(as_unit_quaternions(quaternion),
                                             quaternion_inverse(home)))


def _hull(points: FloatArray) -> FloatArray:
    """The vertices of the convex hull of points (N, 3) m; their bounding box's corners when
    they span no volume (fewer than 4 poses, or all in a plane)."""
    import scipy.spatial  # here: ~0.2 s of a start; a positioner imports it with a calibration

    try:
        hull = scipy.spatial.ConvexHull(points)
        out: FloatArray = points[hull.vertices]
        return out
    except (scipy.spatial.QhullError, ValueError):
        low, high = points.min(axis=0), points.max(axis=0)
        corners = np.array([[(low, high)[(k >> a) & 1][a] for a in range(3)]
                            for k in range(8)])
        return corners


@dataclass(frozen=True)
class Envelope:
    """``mass`` (low, high) kg of the payloads, ``temperature`` (low, high) °C (None: not
    recorded), ``hull`` (K, 3) m the vertices of the measured positions' convex hull (base
    frame), ``rotation`` rad the largest rotation from home."""

    mass: tuple[float, float]
    temperature: tuple[float, float] | None
    hull: FloatArray
    rotation: float

    def reasons(self, mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                mass: float | None = None,
                temperature: ArrayLike | None = None) -> list[tuple[str, ...]]:
        """Per pose (N, 3) m, (N, 4), why it lies outside the envelope (an empty tuple: it is
        inside); ``mass`` kg of the payload carried and ``temperature`` °C (one or (N,)), when
        known."""
        p, q = as_pose_batch(position, quaternion)
        n = p.shape[0]
        out: list[list[str]] = [[] for _ in range(n)]
        common: list[str] = []
        low, high = self.mass
        if mass is not None and not low <= mass <= high:
            common.append(f'payload {mass:g} kg outside the calibrated {low:g} to {high:g} kg')
        if temperature is not None:
            t = np.broadcast_to(np.asarray(temperature, dtype=float), (n,))
            for k in range(n):
                if self.temperature is None:
                    out[k].append('the calibration recorded no temperature')
                elif not self.temperature[0] <= t[k] <= self.temperature[1]:
                    out[k].append(f'temperature {t[k]:.1f} degC outside the calibrated '
                                  f'{self.temperature[0]:.1f} to {self.temperature[1]:.1f} '
                                  'degC')
        import scipy.spatial  # here, as in _hull

        hull = scipy.spatial.ConvexHull(self.hull) if _spans_volume(self.hull) else None
        if hull is not None:
            distance = (p @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)
        else:
            lo, hi = self.hull.min(axis=0), self.hull.max(axis=0)
            distance = np.maximum(lo - p, p - hi).max(axis=1)
        angle = rotation_from_home(mech, q)
        for k in range(n):
            if distance[k] > HULL_MARGIN:
                out[k].append(f'position {distance[k] * 1e3:.2f} mm outside the measured '
                              'positions')
            if angle[k] > self.rotation + ROTATION_MARGIN:
                out[k].append(f'rotation {math.degrees(angle[k]):.2f} deg beyond the '
                              f'calibrated {math.degrees(self.rotation):.2f} deg')
        return [tuple(common + r) for r in out]

    def to_document(self) -> dict[str, Any]:
        """The calibration file's ``envelope`` entry."""
        return {'mass_kg': list(self.mass),
                'temperature_degc': None if self.temperature is None
                else list(self.temperature),
                'max_rotation_rad': self.rotation,
                'hull_m': [[float(v) for v in row] for row in self.hull]}

    @classmethod
    def from_document(cls, doc: Any) -> Envelope:
        """The envelope of a file's entry (InputError naming what is wrong)."""
        if not isinstance(doc, Mapping):
            raise InputError('envelope must be a mapping')
        try:
            mass = np.asarray(doc['mass_kg'], dtype=float)
            temp = doc.get('temperature_degc')
            temperature = None if temp is None else np.asarray(temp, dtype=float)
            rotation = float(doc['max_rotation_rad'])
            hull = np.asarray(doc['hull_m'], dtype=float)
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f'envelope: {err}') from None
        if mass.shape != (2,) or not np.all(np.isfinite(mass)) or mass[0] > mass[1]:
            raise InputError('envelope.mass_kg must be [low, high] kg')
        if temperature is not None and (temperature.shape != (2,)
                                        or not np.all(np.isfinite(temperature))
                                        or temperature[0] > temperature[1]):
            raise InputError('envelope.temperature_degc must be [low, high] degC or null')
        if hull.ndim != 2 or hull.shape[1:] != (3,) or hull.shape[0] < 1 \
                or not np.all(np.isfinite(hull)):
            raise InputError('envelope.hull_m must be a list of positions [x, y, z] m')
        if not math.isfinite(rotation) or rotation < 0.0:
            raise InputError('envelope.max_rotation_rad must be a finite angle >= 0')
        return cls((float(mass[0]), float(mass[1])),
                   None if temperature is None
                   else (float(temperature[0]), float(temperature[1])), hull, rotation)


def _spans_volume(points: FloatArray) -> bool:
    if points.shape[0] < 4:
        return False
    centred = points - points.mean(axis=0)
    return bool(np.linalg.matrix_rank(centred, tol=1e-9) == 3)


def envelope_of(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike, mass: float,
                temperature: ArrayLike | None = None) -> Envelope:
    """The envelope of measured poses (N, 3) m, (N, 4), the payload ``mass`` kg they carried,
    and their temperatures (N,) °C (None: not recorded)."""
    p, q = as_pose_batch(position, quaternion)
    t = None if temperature is None else np.asarray(temperature, dtype=float)
    return Envelope((float(mass), float(mass)),
                    None if t is None or t.size == 0 else (float(t.min()), float(t.max())),
                    _hull(p), float(rotation_from_home(mech, q).max()))
