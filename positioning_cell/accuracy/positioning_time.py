"""Positioning time (ISO 9283:1998 §9) of a commanded path over its cycles. Pure library.

A visit's positioning time is the time from its segment's start (the target took effect: the
positioner began the move) to the final entry of the tracker's readings into the limit band
of pose stabilisation around the attained position (§7.4's band; the stabilised state), with
its U (k = 2) from where between two readings that entry may have happened and the readings'
errors (:func:`positioning_cell.accuracy.stabilisation.stabilisation`). A path's figure is
the mean over the cycles that moved along it, with the largest; U of the mean is the mean of
the visits' U (their errors taken as fully correlated: the side that cannot understate it).

The standard's minimum positioning time is that of moves at the machine's fastest speed and
acceleration over a series of distances; here the distances are those of the program's
paths and the speed the positioner's configured motion limits (its fastest: a move's speed
scale is at most 1), which the record states.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from positioning_cell.accuracy.stabilisation import Stabilisation, plain


@dataclass(frozen=True)
class PositioningTime:
    """A path's positioning time (s): the ``mean`` and the largest (``longest``) over the
    ``cycles`` whose readings stabilised, U (k = 2) of the mean (NaN: a visit stated none),
    and the path's ``distance`` (m)."""

    distance: float
    mean: float
    longest: float
    u: float
    cycles: int

    def to_dict(self) -> dict[str, float | int | bool | None]:
        """JSON-able (SI; NaN as null)."""
        return plain(self.__dict__)


def positioning_time_of(distance: float, visits: Sequence[Stabilisation]
                        ) -> PositioningTime | None:
    """The :class:`PositioningTime` of a path of length ``distance`` (m) from its visits'
    stabilisation records (None: no visit has a positioning time)."""
    timed = [v for v in visits if math.isfinite(v.positioning_time)]
    if not timed:
        return None
    time = np.array([v.positioning_time for v in timed])
    u = np.array([v.positioning_time_u for v in timed])
    return PositioningTime(float(distance), float(time.mean()), float(time.max()),
                           float(u.mean()), len(timed))
