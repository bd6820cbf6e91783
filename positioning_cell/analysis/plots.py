"""Plots (PNG) of a recorded run, in µm and degrees: the error over time with the moves marked,
the per-axis error per pose, the attained poses around each commanded pose and the error
distribution per compensation mode. Each draws what the analysis kept, never the samples one by
one: the error over time is the bounded envelope of :mod:`positioning_cell.analysis.trace`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.analysis.accuracy_map import mapped
from positioning_cell.analysis.replay import LabelledVisit
from positioning_cell.analysis.summary import RunAnalysis
from positioning_cell.plotting import colours, figure, log_scale, save

FloatArray = NDArray[np.float64]
UM = 1e6
DEG = 180.0 / math.pi
#: Up to this many moves each is marked and named in the error-over-time plot.
MAX_MARKED_MOVES = 200


def _visit_errors(visits: Sequence[LabelledVisit]) -> tuple[FloatArray, FloatArray]:
    """Attained minus commanded of each visit: Δp (n, 3) m, rotation vectors (n, 3) rad."""
    if not visits:
        return np.empty((0, 3)), np.empty((0, 3))
    return accuracy.measurement_error([v.visit.position for v in visits],
                                      [v.visit.quaternion for v in visits],
                                      [v.visit.commanded_position for v in visits],
                                      [v.visit.commanded_quaternion for v in visits])


def plot_error_over_time(analysis: RunAnalysis, path: Path) -> Path:
    """|Δp| (µm) and rotation angle (°) of the measurements against their target over the run
    (log scale; the band from the smallest to the largest error of each time bin), moves
    marked with their pose (up to :data:`MAX_MARKED_MOVES`), modes shaded, settled visits
    dotted."""
    r = analysis.replay
    env = r.measured.errors
    t0 = float(env.time[0]) if env.time.size else 0.0
    fig, axes = figure(12, 6.5, 2, 1, sharex=True, margins=(0.07, 0.98, 0.94, 0.08),
                       space=(0.2, 0.08))
    axes = axes[:, 0]
    time = env.time - t0
    for ax, low, high, scale, unit in ((axes[0], env.position_min, env.position_max, UM,
                                        '|Δp| µm'),
                                       (axes[1], env.angle_min, env.angle_max, DEG, 'angle °')):
        lo, hi = np.maximum(low * scale, 1e-3), np.maximum(high * scale, 1e-3)
        ax.fill_between(time, lo, hi, step='mid', color='0.2', lw=0.6)
        log_scale(ax)
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
    tol = analysis.settings.tolerance
    axes[0].axhline(tol.position * UM, color='red', ls='--', lw=0.8, label='tolerance')
    axes[1].axhline(tol.orientation * DEG, color='red', ls='--', lw=0.8)
    segs = r.segments
    end = float(time[-1]) if time.size else 1.0
    starts = np.array([s.time - t0 for s in segs])
    mode_colour = colours([s.mode for s in analysis.modes] or ['measured'])
    changes = [i for i in range(len(segs)) if i == 0 or segs[i - 1].mode != segs[i].mode]
    spans: dict[Any, list[tuple[float, float]]] = {}  # colour: (start, length) of its blocks
    for n, i in enumerate(changes):  # one shaded span per block of moves in one mode
        stop = float(starts[changes[n + 1]]) if n + 1 < len(changes) else end
        spans.setdefault(mode_colour.get(segs[i].mode, '0.9'), []).append(
            (float(starts[i]), stop - float(starts[i])))
    for colour, blocks in spans.items():  # one artist per colour and axes, not per block
        for ax in axes:
            ax.broken_barh(blocks, (0, 1), transform=ax.get_xaxis_transform(), color=colour,
                           alpha=0.08, lw=0)
    if len(segs) <= MAX_MARKED_MOVES:  # beyond, the marks would hide the curve
        for ax in axes:
            ax.vlines(starts, 0, 1, transform=ax.get_xaxis_transform(), color='0.5', lw=0.5)
        for s, start in zip(segs, starts, strict=True):
            axes[0].annotate(s.pose, (float(start), 1.0), xycoords=('data', 'axes fraction'),
                             fontsize=6, va='bottom', rotation=90)
    for mode, colour in mode_colour.items():
        mine = [v for v in r.visits if v.mode == mode]
        settled = np.array([v.visit.settle_time - t0 for v in mine])
        axes[0].plot(settled, [v.verdict.position_error * UM for v in mine], 'o', ms=3,
                     color=colour)
        axes[1].plot(settled, [v.verdict.orientation_error * DEG for v in mine], 'o', ms=3,
                     color=colour)
    from matplotlib.patches import Rectangle

    handles = [Rectangle((0, 0), 1, 1, color=c, alpha=0.4) for c in mode_colour.values()]
    axes[0].legend(handles, list(mode_colour), loc='upper right', fontsize=7, title='mode')
    axes[1].set_xlabel('time since the first measurement, s')
    fig.suptitle('Measured pose minus commanded pose (band: min to max per time bin; lines: '
                 'moves; dots: settled poses)', y=0.99)
    return save(fig, path)


def _grouped(analysis: RunAnalysis, mode: str
             ) -> tuple[list[str], FloatArray, FloatArray, NDArray[np.intp]]:
    """The pose names of a mode (in order), the errors Δp, rotation vectors of its visits
    and the index of each visit's pose among the names."""
    visits = [v for v in analysis.replay.visits if v.mode == mode]
    names = [p.pose for m in analysis.modes if m.mode == mode for p in m.poses]
    dp, rv = _visit_errors(visits)
    index = np.array([names.index(v.pose) for v in visits], dtype=np.intp)
    return names, dp, rv, index


def _per_pose(index: NDArray[np.intp], values: FloatArray, count: NDArray[np.intp]
              ) -> FloatArray:
    """The mean of the rows of ``values`` (n, 3) per pose (``index``: each row's pose,
    ``count``: the rows of each pose, at least 1): (poses, 3)."""
    return np.stack([np.bincount(index, values[:, k], minlength=count.size)
                     for k in range(values.shape[1])], axis=1) / count[:, None]


def plot_axis_errors(analysis: RunAnalysis, path: Path) -> Path:
    """Per mode (columns): the mean error per axis of each pose over its cycles, with the
    standard deviation as error bars: Δx, Δy, Δz (µm) and rotation vector x, y, z (°)."""
    from matplotlib.patches import Rectangle

    modes = analysis.modes
    cols = max(len(modes), 1)
    fig, axes = figure(4.2 * cols, 6.5, 2, cols, margins=(0.06, 0.99, 0.9, 0.06),
                       space=(0.3, 0.3))
    axis_colour = ['C0', 'C1', 'C2']  # x, y, z
    for col, mode in enumerate(modes):
        names, dp, rv, index = _grouped(analysis, mode.mode)
        x = np.arange(len(names))
        count = np.maximum(np.bincount(index, minlength=len(names)), 1)
        for row, (values, scale, unit) in enumerate(((dp, UM, 'µm'), (rv, DEG, '°'))):
            ax = axes[row, col]
            v = values * scale
            mean = _per_pose(index, v, count)
            var = _per_pose(index, (v - mean[index]) ** 2, count)
            # one call for the three axes' bars: x, y, z side by side at each pose
            ax.bar((x[:, None] + (np.arange(3) - 1) * 0.27).ravel(), mean.ravel(), 0.27,
                   yerr=np.sqrt(var).ravel(), capsize=2, color=axis_colour * len(names))
            ax.axhline(0.0, color='k', lw=0.5)
            ax.set_xticks(x, names)
            ax.set_ylabel(unit)
            ax.grid(True, axis='y', alpha=0.3)
            ax.set_title(f'{mode.mode}: {"position" if row == 0 else "orientation"}',
                         fontsize=9)
            if col == 0:  # the same colours in every column: one legend per row
                ax.legend([Rectangle((0, 0), 1, 1, color=c) for c in axis_colour],
                          [f'{"Δ" if row == 0 else "r"}{a}' for a in 'xyz'], fontsize=7)
    fig.suptitle('Error per axis per pose (attained minus commanded; bars: mean over cycles, '
                 'whiskers: std)', fontsize=10)
    return save(fig, path)


#: Poses per row of the clusters plot: more wrap to the next row (23 poses in one row drew
#: 8096 × 704 px, issue 26).
CLUSTER_COLUMNS = 6


def plot_clusters(analysis: RunAnalysis, path: Path) -> Path:
    """Per commanded pose of the program (:data:`CLUSTER_COLUMNS` to a row): the attained
    positions relative to it (µm), x-y (top) and x-z (below it), one colour per mode, crosses
    at each mode's barycentre (ISO AP). The visits of no mode of the program (before it:
    calibration, homing) are not drawn and get no panel."""
    mode_colour = colours([m.mode for m in analysis.modes])
    visits = [v for v in analysis.replay.visits if v.mode in mode_colour]
    poses = list(dict.fromkeys(v.pose for v in sorted(visits, key=lambda v: v.visit.key)))
    columns = min(max(len(poses), 1), CLUSTER_COLUMNS)
    rows = max(math.ceil(len(poses) / columns), 1)
    fig, grid = figure(3.2 * columns, 6.4 * rows, 2 * rows, columns,
                       margins=(0.05, 0.99, 1.0 - 0.75 / (6.4 * rows), 0.5 / (6.4 * rows)),
                       space=(0.35, 0.3))
    for k in range(len(poses), rows * columns):  # the empty cells of the last row
        grid[2 * (k // columns), k % columns].set_visible(False)
        grid[2 * (k // columns) + 1, k % columns].set_visible(False)
    dp, _ = _visit_errors(visits)
    pose_of = np.array([v.pose for v in visits], dtype=object)
    mode_of = np.array([v.mode for v in visits], dtype=object)
    for k, pose in enumerate(poses):
        for row, (i, j) in enumerate(((0, 1), (0, 2))):
            ax = grid[2 * (k // columns) + row, k % columns]
            for mode, colour in mode_colour.items():
                sel = (pose_of == pose) & (mode_of == mode)
                if not sel.any():
                    continue
                pts = dp[sel] * UM
                ax.plot(pts[:, i], pts[:, j], 'o', ms=4, color=colour, label=mode,
                        alpha=0.8)  # markers of one line: cheaper to draw than a scatter
                ax.plot(*pts[:, [i, j]].mean(axis=0), 'x', color=colour, ms=9)
            ax.plot(0.0, 0.0, '+', color='k', ms=12)
            ax.set_xlabel(f'Δ{"xyz"[i]} µm')
            ax.set_ylabel(f'Δ{"xyz"[j]} µm')
            ax.grid(True, alpha=0.3)
            ax.set_aspect('equal', adjustable='datalim')
            if row == 0:
                ax.set_title(pose)
    if poses:
        grid[0, 0].legend(fontsize=7)
    fig.suptitle('Attained poses around each commanded pose (+: commanded, x: barycentre)',
                 fontsize=10, y=1.0 - 0.15 / (6.4 * rows))  # inches from the top, any height
    return save(fig, path)


def plot_error_distribution(analysis: RunAnalysis, path: Path) -> Path:
    """Per mode: the distribution of the settled pose errors |Δp| (µm) and angle (°), box
    plots with every visit drawn, the tolerances dashed."""
    modes = [m.mode for m in analysis.modes]
    fig, axes = figure(10, 4.5, 1, 2, margins=(0.07, 0.98, 0.9, 0.08), space=(0.25, 0.2))
    tol = analysis.settings.tolerance
    for ax, attr, scale, unit, limit in (
            (axes[0, 0], 'position_error', UM, '|Δp| µm', tol.position * UM),
            (axes[0, 1], 'orientation_error', DEG, 'angle °', tol.orientation * DEG)):
        data = [np.array([getattr(v.verdict, attr) for v in analysis.replay.visits
                          if v.mode == m]) * scale for m in modes]
        if modes:
            ax.boxplot(data, tick_labels=modes, whis=(0, 100))
            for k, values in enumerate(data):
                jitter = np.linspace(-0.12, 0.12, values.size) if values.size > 1 else [0.0]
                ax.plot(k + 1 + np.asarray(jitter), values, '.', alpha=0.6)
        ax.axhline(limit, color='red', ls='--', lw=0.8, label='tolerance')
        log_scale(ax)
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle('Settled pose error per compensation mode', fontsize=10)
    return save(fig, path)


def plot_accuracy_map(analysis: RunAnalysis, path: Path) -> Path:
    """The accuracy map (:mod:`positioning_cell.analysis.accuracy_map`): AP_p (top) and RP_l
    (bottom) of each commanded pose of the mapped modes (µm, whiskers: U, k = 2) against its
    commanded x, y and z (mm, one column per axis), one colour per mode."""
    modes = mapped(analysis.modes)
    mode_colour = colours([m.mode for m in modes])
    fig, axes = figure(12, 6.5, 2, 3, margins=(0.06, 0.99, 0.9, 0.08), space=(0.25, 0.3),
                       sharey='row')
    for m in modes:
        at = np.array([p.figures.commanded_position for p in m.poses]) * 1e3
        ap = np.array([p.figures.ap_p for p in m.poses]) * UM
        u_ap = np.array([p.uncertainty.ap_p for p in m.poses]) * UM
        rp = np.array([np.nan if p.figures.rp_l is None else p.figures.rp_l
                       for p in m.poses]) * UM
        u_rp = np.array([p.uncertainty.rp_l for p in m.poses]) * UM
        for axis in range(3):
            for row, (values, u) in enumerate(((ap, u_ap), (rp, u_rp))):
                axes[row, axis].errorbar(at[:, axis], values, yerr=np.nan_to_num(u), fmt='o',
                                         ms=3, elinewidth=0.6, capsize=0, alpha=0.7,
                                         color=mode_colour[m.mode], label=m.mode)
    for axis in range(3):
        axes[1, axis].set_xlabel(f'commanded {"xyz"[axis]} mm')
        for row in range(2):
            axes[row, axis].grid(True, alpha=0.3)
    axes[0, 0].set_ylabel('AP_p µm')
    axes[1, 0].set_ylabel('RP_l µm')
    if modes:
        axes[0, 0].legend(fontsize=7)
    fig.suptitle('Accuracy map: ISO 9283 AP_p and RP_l of each pose against each axis '
                 '(whiskers: U, k = 2)', fontsize=10)
    return save(fig, path)


#: File name of each plot, in the order the report lists them.
ERROR_OVER_TIME, AXIS_ERRORS, CLUSTERS, ACCURACY_MAP, ERROR_DISTRIBUTION = (
    'error_over_time.png', 'axis_errors.png', 'clusters.png', 'accuracy_map.png',
    'error_distribution.png')
_DRAW = {ERROR_OVER_TIME: plot_error_over_time, AXIS_ERRORS: plot_axis_errors,
         CLUSTERS: plot_clusters, ACCURACY_MAP: plot_accuracy_map,
         ERROR_DISTRIBUTION: plot_error_distribution}


def plot_names(analysis: RunAnalysis) -> list[str]:
    """The file names of the plots of ``analysis``, in report order: without a settled visit
    only the error over time; with a mapped mode
    (:data:`~positioning_cell.analysis.accuracy_map.MAP_LEAST` poses or more) the accuracy
    map instead of the per-pose plots (a subplot or a bar group per pose does not scale to a
    hundred poses); else the per-pose plots."""
    if not analysis.replay.visits:
        return [ERROR_OVER_TIME]
    if mapped(analysis.modes):
        return [ERROR_OVER_TIME, ACCURACY_MAP, ERROR_DISTRIBUTION]
    return [ERROR_OVER_TIME, AXIS_ERRORS, CLUSTERS, ERROR_DISTRIBUTION]


def draw_plots(analysis: RunAnalysis, out_dir: Path, names: Sequence[str]) -> list[Path]:
    """The plots ``names`` (of :func:`plot_names`) of ``analysis`` into ``out_dir``
    (created); their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return [_DRAW[name](analysis, out_dir / name) for name in names]


def write_plots(analysis: RunAnalysis, out_dir: Path) -> list[Path]:
    """All plots into ``out_dir`` (created), one after the other in this process; their
    paths (:func:`plot_names`)."""
    return draw_plots(analysis, out_dir, plot_names(analysis))
