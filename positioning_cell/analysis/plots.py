"""Plots (PNG, matplotlib Agg) of a recorded run, in µm and degrees: the error over time with
the moves marked, the per-axis error per pose, the attained poses around each commanded pose
and the error distribution per compensation mode."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.analysis.replay import LabelledVisit
from positioning_cell.analysis.summary import RunAnalysis

FloatArray = NDArray[np.float64]
UM = 1e6
DEG = 180.0 / math.pi
#: Up to this many moves each is marked and named in the error-over-time plot.
MAX_MARKED_MOVES = 200


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def _colours(modes: Sequence[str]) -> dict[str, Any]:
    cmap = _pyplot().get_cmap('tab10')
    return {m: cmap(i % 10) for i, m in enumerate(modes)}


def _visit_errors(visits: Sequence[LabelledVisit]) -> tuple[FloatArray, FloatArray]:
    """Attained minus commanded of each visit: Δp (n, 3) m, rotation vectors (n, 3) rad."""
    return accuracy.measurement_error([v.visit.position for v in visits],
                                      [v.visit.quaternion for v in visits],
                                      [v.visit.commanded_position for v in visits],
                                      [v.visit.commanded_quaternion for v in visits])


def plot_error_over_time(analysis: RunAnalysis, path: Path) -> Path:
    """|Δp| (µm) and rotation angle (°) of every measurement against its target over the run
    (log scale), moves marked with their pose (up to :data:`MAX_MARKED_MOVES`), modes shaded,
    settled visits dotted."""
    plt = _pyplot()
    r = analysis.replay
    m = r.measured
    t0 = float(m.time[0]) if m.count else 0.0
    fig, axes = plt.subplots(2, 1, figsize=(12, 6.5), sharex=True)
    ok = ~np.isnan(m.position_error[:, 0])
    d = np.linalg.norm(m.position_error[ok], axis=1) * UM
    a = np.linalg.norm(m.orientation_error[ok], axis=1) * DEG
    colours = _colours([s.mode for s in analysis.modes] or ['measured'])
    for ax, values, unit in ((axes[0], d, '|Δp| µm'), (axes[1], a, 'angle °')):
        ax.plot(m.time[ok] - t0, np.maximum(values, 1e-3), lw=0.8, color='0.2')
        ax.set_yscale('log')
        ax.set_ylabel(unit)
        ax.grid(True, which='both', alpha=0.3)
    tol = analysis.settings.tolerance
    axes[0].axhline(tol.position * UM, color='red', ls='--', lw=0.8, label='tolerance')
    axes[1].axhline(tol.orientation * DEG, color='red', ls='--', lw=0.8)
    segs = r.segments
    end = float(m.time[-1]) - t0 if m.count else 1.0
    starts = [s.time - t0 for s in segs]
    for i, s in enumerate(segs):  # one shaded span per block of moves in one mode
        if i == 0 or segs[i - 1].mode != s.mode:
            stop = next((starts[j] for j in range(i + 1, len(segs))
                         if segs[j].mode != s.mode), end)
            for ax in axes:
                ax.axvspan(starts[i], stop, color=colours.get(s.mode, '0.9'), alpha=0.08,
                           lw=0)
    if len(segs) <= MAX_MARKED_MOVES:  # beyond, the marks would hide the curve
        for ax in axes:
            ax.vlines(starts, 0, 1, transform=ax.get_xaxis_transform(), color='0.5', lw=0.5)
        for s, start in zip(segs, starts, strict=True):
            axes[0].annotate(s.pose, (start, 1.0), xycoords=('data', 'axes fraction'),
                             fontsize=6, va='bottom', rotation=90)
    for mode, colour in colours.items():
        mine = [v for v in r.visits if v.mode == mode]
        settled = np.array([v.visit.settle_time - t0 for v in mine])
        axes[0].plot(settled, [v.verdict.position_error * UM for v in mine], 'o', ms=3,
                     color=colour)
        axes[1].plot(settled, [v.verdict.orientation_error * DEG for v in mine], 'o', ms=3,
                     color=colour)
    handles = [plt.Rectangle((0, 0), 1, 1, color=c, alpha=0.4) for c in colours.values()]
    axes[0].legend(handles, list(colours), loc='upper right', fontsize=7, title='mode')
    axes[1].set_xlabel('time since the first measurement, s')
    fig.suptitle('Measured pose minus commanded pose (lines: moves; dots: settled poses)',
                 y=0.995)
    return _save(fig, path)


def plot_axis_errors(analysis: RunAnalysis, path: Path) -> Path:
    """Per mode (columns): the mean error per axis of each pose over its cycles, with the
    standard deviation as error bars: Δx, Δy, Δz (µm) and rotation vector x, y, z (°)."""
    plt = _pyplot()
    modes = analysis.modes
    fig, axes = plt.subplots(2, max(len(modes), 1), figsize=(4.2 * max(len(modes), 1), 6.5),
                             squeeze=False)
    for col, mode in enumerate(modes):
        visits = [v for v in analysis.replay.visits if v.mode == mode.mode]
        dp, rv = _visit_errors(visits)
        names = [p.pose for p in mode.poses]
        x = np.arange(len(names))
        for row, (values, scale, unit) in enumerate(((dp, UM, 'µm'), (rv, DEG, '°'))):
            ax = axes[row, col]
            for k, axis in enumerate('xyz'):
                mean = [values[[v.pose == n for v in visits]][:, k].mean() * scale
                        for n in names]
                std = [values[[v.pose == n for v in visits]][:, k].std() * scale
                       for n in names]
                ax.bar(x + (k - 1) * 0.27, mean, 0.27, yerr=std, capsize=2,
                       label=f'{"Δ" if row == 0 else "r"}{axis}')
            ax.axhline(0.0, color='k', lw=0.5)
            ax.set_xticks(x, names)
            ax.set_ylabel(unit)
            ax.grid(True, axis='y', alpha=0.3)
            ax.set_title(f'{mode.mode}: {"position" if row == 0 else "orientation"}',
                         fontsize=9)
            ax.legend(fontsize=7)
    fig.suptitle('Error per axis per pose (attained minus commanded; bars: mean over cycles, '
                 'whiskers: std)', fontsize=10)
    return _save(fig, path)


def plot_clusters(analysis: RunAnalysis, path: Path) -> Path:
    """Per commanded pose (columns): the attained positions relative to it (µm), x-y (top)
    and x-z (bottom), one colour per mode, crosses at each mode's barycentre (ISO AP)."""
    plt = _pyplot()
    visits = analysis.replay.visits
    poses = list(dict.fromkeys(v.pose for v in sorted(visits, key=lambda v: v.visit.key)))
    colours = _colours([m.mode for m in analysis.modes])
    n = max(len(poses), 1)
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 6.4), squeeze=False)
    dp, _ = _visit_errors(visits) if visits else (np.empty((0, 3)), None)
    for col, pose in enumerate(poses):
        for row, (i, j) in enumerate(((0, 1), (0, 2))):
            ax = axes[row, col]
            for mode, colour in colours.items():
                sel = np.array([v.pose == pose and v.mode == mode for v in visits])
                if not sel.any():
                    continue
                pts = dp[sel] * UM
                ax.scatter(pts[:, i], pts[:, j], s=14, color=colour, label=mode, alpha=0.8)
                ax.plot(*pts[:, [i, j]].mean(axis=0), 'x', color=colour, ms=9)
            ax.plot(0.0, 0.0, '+', color='k', ms=12)
            ax.set_xlabel(f'Δ{"xyz"[i]} µm')
            ax.set_ylabel(f'Δ{"xyz"[j]} µm')
            ax.grid(True, alpha=0.3)
            ax.set_aspect('equal', adjustable='datalim')
            if row == 0:
                ax.set_title(pose)
    if poses:
        axes[0, 0].legend(fontsize=7)
    fig.suptitle('Attained poses around each commanded pose (+: commanded, x: barycentre)',
                 fontsize=10)
    return _save(fig, path)


def plot_error_distribution(analysis: RunAnalysis, path: Path) -> Path:
    """Per mode: the distribution of the settled pose errors |Δp| (µm) and angle (°), box
    plots with every visit drawn, the tolerances dashed."""
    plt = _pyplot()
    modes = [m.mode for m in analysis.modes]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    tol = analysis.settings.tolerance
    for ax, attr, scale, unit, limit in (
            (axes[0], 'position_error', UM, '|Δp| µm', tol.position * UM),
            (axes[1], 'orientation_error', DEG, 'angle °', tol.orientation * DEG)):
        data = [np.array([getattr(v.verdict, attr) for v in analysis.replay.visits
                          if v.mode == m]) * scale for m in modes]
        if modes:
            ax.boxplot(data, tick_labels=modes, whis=(0, 100))
            for k, values in enumerate(data):
                jitter = np.linspace(-0.12, 0.12, values.size) if values.size > 1 else [0.0]
                ax.plot(k + 1 + np.asarray(jitter), values, '.', alpha=0.6)
        ax.axhline(limit, color='red', ls='--', lw=0.8, label='tolerance')
        ax.set_yscale('log')
        ax.set_ylabel(unit)
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle('Settled pose error per compensation mode', fontsize=10)
    return _save(fig, path)


def write_plots(analysis: RunAnalysis, out_dir: Path) -> list[Path]:
    """All plots into ``out_dir`` (created); their paths. Without a settled visit only the
    error over time is drawn."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [plot_error_over_time(analysis, out_dir / 'error_over_time.png')]
    if analysis.replay.visits:
        paths += [plot_axis_errors(analysis, out_dir / 'axis_errors.png'),
                  plot_clusters(analysis, out_dir / 'clusters.png'),
                  plot_error_distribution(analysis, out_dir / 'error_distribution.png')]
    return paths


def _save(fig: Any, path: Path) -> Path:
    """Lay out, write as PNG (110 dpi) and release a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path
