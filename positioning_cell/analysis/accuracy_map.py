"""The accuracy map of a run (issue 25): ISO 9283 pose accuracy AP_p and repeatability RP_l
over many poses spread over the workspace (a ``program.grid``, config/accuracy_map.yaml),
summarised per compensation mode: the box the poses span, the mean and the worst of each
figure and where the worst lies. The figures are the summary's per pose
(:mod:`positioning_cell.analysis.summary`, each with its U); the report's section and its
plot (:func:`positioning_cell.analysis.plots.plot_accuracy_map`) show them against each axis
of the base frame."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from positioning_cell.analysis.summary import ModeSummary, PoseSummary

#: A mode with at least this many commanded poses is mapped (the per-pose plots, one subplot
#: or bar group per pose, give way to the map; the issue asks 100 poses or more for a map).
MAP_LEAST = 20


@dataclass(frozen=True)
class MapSummary:
    """One mode's map: how many ``poses``, the ``low`` and ``high`` corners (m, base) of the
    box their commanded positions span, AP_p's mean and largest (m) and the pose it is
    largest at, RP_l's likewise (NaN and '' when no pose has two cycles)."""

    mode: str
    poses: int
    low: tuple[float, float, float]
    high: tuple[float, float, float]
    ap_p_mean: float
    ap_p_max: float
    ap_p_worst: str
    rp_l_mean: float
    rp_l_max: float
    rp_l_worst: str


def mapped(modes: Sequence[ModeSummary]) -> tuple[ModeSummary, ...]:
    """The modes with at least :data:`MAP_LEAST` commanded poses."""
    return tuple(m for m in modes if len(m.poses) >= MAP_LEAST)


def map_summary(mode: ModeSummary) -> MapSummary:
    """The :class:`MapSummary` of one mode's poses."""
    poses = mode.poses
    commanded = np.array([p.figures.commanded_position for p in poses])
    ap = np.array([p.figures.ap_p for p in poses])
    rp = np.array([math.nan if p.figures.rp_l is None else p.figures.rp_l for p in poses])
    worst_ap = int(np.argmax(ap))
    has_rp = np.isfinite(rp)
    worst_rp = int(np.nanargmax(rp)) if has_rp.any() else -1
    low, high = commanded.min(axis=0), commanded.max(axis=0)
    return MapSummary(
        mode.mode, len(poses), (float(low[0]), float(low[1]), float(low[2])),
        (float(high[0]), float(high[1]), float(high[2])), float(ap.mean()),
        float(ap[worst_ap]), poses[worst_ap].pose,
        float(rp[has_rp].mean()) if has_rp.any() else math.nan,
        float(rp[worst_rp]) if worst_rp >= 0 else math.nan,
        poses[worst_rp].pose if worst_rp >= 0 else '')


def pose_at(mode: ModeSummary, name: str) -> PoseSummary:
    """The pose ``name`` of a mode."""
    return next(p for p in mode.poses if p.pose == name)


__all__ = ['MAP_LEAST', 'MapSummary', 'map_summary', 'mapped', 'pose_at']
