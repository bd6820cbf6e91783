"""Drift of pose characteristics (ISO 9283:1998 §7.6) of one commanded pose: how far its pose
accuracy and repeatability at the end of a run lie from those at its start, with their
expanded uncertainty U (k = 2). SI: m, rad, s.

ISO 9283 compares the characteristics at the start of the drift test (t = 1) with those at its
end (t = T): dAP = |AP(t = T) − AP(t = 1)| and dRP = |RP(t = T) − RP(t = 1)|, for the position
(dAP_p, dRP_l) and each angle (dAP_a..c, dRP_a..c). Here the characteristics at the start and
at the end are those of the first and of the last third of the pose's visits in time order
(:func:`epoch_size`), computed
as every other pose figure (:func:`positioning_cell.accuracy.iso9283.iso9283`); the cell's
temperature drift, the machine's wear-in and the tracker's own drift all show in them, as on
a real cell, and only the run's length and its cycles decide how much of it the figures see
(the times of the two epochs are part of the result).

U: a drift figure is the difference of two figures, each measured with its own U
(:mod:`positioning_cell.accuracy.figure_uncertainty`), the epochs' visits disjoint.

- dAP: the two accuracies' errors are the epochs' mean measurement errors, independent but
  for the part every reading shares (the tracker's registration), which enters both with the
  same sign: their correlation r ≥ 0, and u² = u₁² + u₂² − 2r·u₁·u₂ ≤ u₁² + u₂². U is the
  quadrature of the two Us (JCGM 100 §5.1.2), which cannot understate it.
- dRP: each U of RP is the quantile of a bound B ≥ 0 of its error (a shared error does not
  move a spread), and |error of dRP| ≤ B₁ + B₂. The Bs are not centred, so their quadrature
  could understate the quantile of the sum; U is the sum of the two Us.

Test: test/test_drift.py (a hand-worked example; the figures of seeded simulated runs from
their true poses lie within U of those from their measurements in ≥ 95 % of runs)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.accuracy.figure_uncertainty import pose_uncertainties
from positioning_cell.accuracy.iso9283 import PoseFigures, iso9283
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.records import plain_fields

#: The drift figures, position first: their names in PoseFigures (ap_p ...) and here (dap_p).
FIGURES = ('ap_p', 'ap_a', 'ap_b', 'ap_c', 'rp_l', 'rp_a', 'rp_b', 'rp_c')

#: The fewest visits of a pose that give its drift: two epochs of two visits at least (RP is
#: a spread), a third of the visits each. Below it, the difference of two visits would be
#: their scatter (repeatability), not a drift.
LEAST_VISITS = 6


def epoch_size(n: int) -> int:
    """How many of a pose's n visits each epoch holds: a third of them (n // 3, the two
    epochs never sharing a visit). InputError below :data:`LEAST_VISITS`."""
    if n < LEAST_VISITS:
        raise InputError(f'a drift (ISO 9283 7.6) needs at least {LEAST_VISITS} visits of '
                         f'the pose, got {n}')
    return n // 3


@dataclass(frozen=True)
class DriftFigures:
    """ISO 9283 §7.6 of one commanded pose (module docstring): the figures of its first and
    last epochs (``first``, ``last``: each :class:`PoseFigures` of ``cycles`` visits), the
    mean time (s) of each epoch's visits, and the drifts, each |last − first| (m, rad), with
    U (k = 2) of each (NaN: not stated)."""

    cycles: int
    time_first: float
    time_last: float
    first: PoseFigures
    last: PoseFigures
    dap_p: float
    dap_a: float
    dap_b: float
    dap_c: float
    drp_l: float
    drp_a: float
    drp_b: float
    drp_c: float
    u_dap_p: float = math.nan
    u_dap_a: float = math.nan
    u_dap_b: float = math.nan
    u_dap_c: float = math.nan
    u_drp_l: float = math.nan
    u_drp_a: float = math.nan
    u_drp_b: float = math.nan
    u_drp_c: float = math.nan

    @property
    def span(self) -> float:
        """Time (s) between the two epochs' mean times (the test's T − 1)."""
        return self.time_last - self.time_first

    def figure(self, name: str) -> tuple[float, float]:
        """A drift figure by its ISO name without the d ('ap_p', 'rp_a' ...) and its U."""
        return float(getattr(self, f'd{name}')), float(getattr(self, f'u_d{name}'))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; None where undefined or, for a U, not stated)."""
        out = plain_fields(self)
        out['first'], out['last'] = self.first.to_dict(), self.last.to_dict()
        for key, value in out.items():
            if isinstance(value, float) and not math.isfinite(value):
                out[key] = None
        return out


def drift_figures(commanded_position: ArrayLike, commanded_quaternion: ArrayLike,
                  attained_position: ArrayLike, attained_quaternion: ArrayLike,
                  times: ArrayLike, covariance: ArrayLike | None = None) -> DriftFigures:
    """ISO 9283 §7.6 of one commanded pose (3,) m, (4,) from its n ≥ 6 attained poses (n, 3)
    m, (n, 4) taken at ``times`` (n,) s (sorted here by time), with the covariances
    (n, 6, 6) they were measured with (position m², then small rotations about the base axes
    rad²; None or NaN: U not stated). InputError: fewer than :data:`LEAST_VISITS` visits,
    wrong shapes, times not finite."""
    position, quaternion = as_pose_batch(attained_position, attained_quaternion)
    n = position.shape[0]
    t = np.asarray(times, dtype=float)
    if t.shape != (n,) or not np.all(np.isfinite(t)):
        raise InputError(f'times: expected {n} finite stamps, got shape {t.shape}')
    cov = (np.full((n, 6, 6), math.nan) if covariance is None
           else np.asarray(covariance, dtype=float))
    if cov.shape != (n, 6, 6):
        raise InputError(f'covariance: expected shape ({n}, 6, 6), got {cov.shape}')
    m = epoch_size(n)
    order = np.argsort(t, kind='stable')
    epochs = (order[:m], order[n - m:])
    figures = [iso9283(commanded_position, commanded_quaternion, position[i], quaternion[i])
               for i in epochs]
    both = np.stack(epochs)  # (2, m): the epochs' U from one Monte Carlo
    stated = [{'ap_p': pose.ap_p, 'rp_l': pose.rp_l, **angles._asdict()}
              for pose, angles in pose_uncertainties(
                  np.tile(np.reshape(commanded_position, (1, 3)), (2, 1)), position[both],
                  quaternion[both], cov[both])]
    values: dict[str, Any] = {}
    for name in FIGURES:
        first, last = (getattr(f, name) for f in figures)
        values[f'd{name}'] = abs(float(last) - float(first))
        u_first, u_last = stated[0][name], stated[1][name]
        values[f'u_d{name}'] = (math.hypot(u_first, u_last) if name.startswith('ap')
                                else u_first + u_last)
    return DriftFigures(cycles=m, time_first=float(t[epochs[0]].mean()),
                        time_last=float(t[epochs[1]].mean()), first=figures[0],
                        last=figures[1], **values)


__all__ = ['FIGURES', 'LEAST_VISITS', 'DriftFigures', 'drift_figures', 'epoch_size']
