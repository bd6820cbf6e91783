"""The trends of a fleet of runs (:mod:`.fleet`) for people and programs: a Markdown report
(µm, degrees, UTC), a JSON document (SI: m, rad, s since the Unix epoch) and PNG plots: AP and
RP per mode over time with a line per pose, the drift since calibration with the epochs
marked, and the tracker's registration residuals over time."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.analysis.fleet import (
    DECISION_KEYS,
    BagFailure,
    Epoch,
    PoseSeries,
    Trends,
)
from positioning_cell.analysis.plots import DEG, UM
from positioning_cell.analysis.report import decided, deg, um, um_u
from positioning_cell.analysis.tables import markdown_table
from positioning_cell.bag.verify import utc
from positioning_cell.plotting import colours, figure, save

FloatArray = NDArray[np.float64]

TRENDS_REPORT_FILE = 'trends.md'
TRENDS_SUMMARY_FILE = 'trends.json'
#: What is left in a table cell without a value (a pose not observed in a run).
NO_VALUE = '–'


def when(time: float | None) -> str:
    """A log time (s since the Unix epoch) as UTC ``YYYY-MM-DD HH:MM:SS`` ('–' for None)."""
    return NO_VALUE if time is None else utc(round(time * 1e9))[:19]


def bag_labels(bags: Sequence[str]) -> dict[str, str]:
    """A short label per bag path: the path below the bags' common folder (the folder name
    itself for a single bag)."""
    if not bags:
        return {}
    if len(set(bags)) == 1:
        return {bags[0]: Path(bags[0]).name}
    common = os.path.commonpath(bags)
    return {b: os.path.relpath(b, common) for b in bags}


def _value(v: float) -> float | None:
    """A float of a series, None for NaN (a figure that is not defined)."""
    return None if np.isnan(v) else float(v)


def _angle_max(values: FloatArray) -> FloatArray:
    """Largest magnitude over the three angles of each row (R, 3) → (R,) rad; NaN if all are."""
    a = np.abs(values)
    return np.where(np.isnan(a).all(axis=1), np.nan,
                    np.nanmax(np.where(np.isnan(a), -np.inf, a), axis=1))


# -- Markdown --------------------------------------------------------------------------------
def _runs_table(trends: Trends, label: dict[str, str]) -> list[str]:
    rows = [[label[r.bag], r.kind, when(r.start),
             f'{r.end - r.start:.0f}', str(r.messages),
             r.calibration or ('none' if r.calibrations else 'not known'),
             ', '.join(r.modes) or NO_VALUE, str(len(r.poses)), str(len(r.problems))]
            for r in trends.runs]
    return markdown_table(('run', 'kind', 'start UTC', 'duration s', 'messages',
                           'calibration in force', 'modes', 'mode × pose', 'problems'), rows)


def _epochs_table(epochs: Sequence[Epoch], label: dict[str, str]) -> list[str]:
    rows = [[str(e.index), when(e.start), e.cause, e.calibration or 'none / not known',
             str(len(e.bags)), ', '.join(label[b] for b in e.bags)] for e in epochs]
    return markdown_table(('epoch', 'from UTC', 'begun by', 'calibration file', 'runs', 'which'),
                  rows)


def _first_last_max(values: FloatArray, text: Callable[[float | None], str]) -> list[str]:
    """First, last and largest value of a series, formatted ('n/a' where undefined)."""
    known = values[~np.isnan(values)]
    return [text(_value(values[0])), text(_value(values[-1])),
            text(float(known.max()) if known.size else None)]


def _pose_summary(series: Sequence[PoseSeries]) -> list[str]:
    rows = []
    for s in series:
        rows.append([s.mode, s.pose.name, ', '.join(f'{v * 1e3:.3f}' for v in s.pose.position),
                     str(s.time.size), *_first_last_max(s.ap_p, um),
                     *_first_last_max(s.rp_l, um),
                     *_first_last_max(_angle_max(s.ap_angles), deg),
                     *_first_last_max(_angle_max(s.rp_angles), deg)])
    return markdown_table(('mode', 'pose', 'commanded x, y, z mm', 'runs', 'AP_p µm first', 'last',
                   'max', 'RP_l µm first', 'last', 'max', 'max |AP_abc| ° first', 'last',
                   'max', 'max RP_abc ± ° first', 'last', 'max'), rows)


def _per_run(trends: Trends, mode: str, label: dict[str, str],
             value: Callable[[PoseSeries, int], str]) -> list[str]:
    """A table with a row per run that has ``mode`` and a column per pose: ``value`` of the
    pose's observation(s) in that run (several: joined by '/'; none: '–')."""
    mine = [s for s in trends.series if s.mode == mode]
    cells: dict[str, dict[int, list[str]]] = {}
    for col, s in enumerate(mine):
        for k, bag in enumerate(s.bags):
            cells.setdefault(bag, {}).setdefault(col, []).append(value(s, k))
    rows = [[label[r.bag], when(r.start),
             *('/'.join(cells[r.bag].get(c, [NO_VALUE])) for c in range(len(mine)))]
            for r in trends.runs if r.bag in cells]
    return markdown_table(('run', 'start UTC', *(s.pose.name for s in mine)), rows)


def _drift_cell(s: PoseSeries, k: int) -> str:
    return f'{um(float(s.drift_distance[k]))} (e{int(s.epoch[k])})'


def _drift_table(trends: Trends) -> list[str]:
    rows = []
    for e in trends.epochs:
        for s in trends.series:
            sel = np.flatnonzero(s.epoch == e.index)
            if sel.size == 0:
                continue
            last = int(sel[-1])
            rows.append([str(e.index), s.mode, s.pose.name, str(sel.size),
                         um(float(s.drift_distance[last])),
                         um(float(s.drift_distance[sel].max())),
                         ', '.join(um(float(v)) for v in s.drift[last]),
                         ', '.join(deg(float(v)) for v in s.drift_angles[last])])
    return markdown_table(('epoch', 'mode', 'pose', 'runs', 'last |Δ| µm', 'max |Δ| µm',
                   'last Δx, Δy, Δz µm', 'last Δa, Δb, Δc °'), rows)


def _registrations_table(trends: Trends, label: dict[str, str]) -> list[str]:
    r = trends.registrations
    rows = [[when(float(r.time[k])), label.get(r.bags[k], r.bags[k]), str(int(r.locations[k])),
             um(_value(r.residual_rms[k])), um(_value(r.residual_max[k])),
             f'{r.variance_factor[k]:.3f}'] for k in range(r.time.size)]
    return markdown_table(('first reported UTC', 'run', 'location #', 'residual RMS µm',
                   'residual max µm', 'variance factor'), rows)


def markdown(trends: Trends, failures: Sequence[BagFailure] = (),
             plots: Sequence[Path] = ()) -> str:
    """The Markdown trend report."""
    runs = trends.runs
    label = bag_labels([r.bag for r in runs])
    out = [f'# Positioning cell fleet trends: {len(runs)} run{"s" if len(runs) != 1 else ""}',
           '']
    if runs:
        out += [f'{len(runs)} bag(s) analysed, from {when(runs[0].start)} to '
                f'{when(runs[-1].end)} UTC; {len(failures)} failed. Times are the bags\' log '
                'times; AP, RP: ISO 9283:1998 §7.2.1 and §7.2.2 over the cycles of each pose '
                'in a run (RP needs two); a pose is one pose across runs when its commanded '
                'pose agrees. Only whole program runs make the trends: an interactive session '
                '(`cell up`, `cell move`: its bag says so, or holds no `/cell/program` step) '
                'and an aborted program (fewer moves marked than its program has, by its '
                'bag\'s description) are listed in the runs and counted in the registrations, '
                'not in the accuracy trends.', '']
    else:
        out += ['No bag could be analysed.', '']
    if failures:
        out += ['## Failed bags', '', *(f'- `{f.bag}`: {f.reason}' for f in failures), '']
    problems = [f'- {label[r.bag]}: {p}' for r in runs for p in r.problems]
    if problems:
        out += ['## Problems', '', 'Each run below was analysed as far as it was readable.',
                '', *problems, '']
    if not runs:
        return '\n'.join(out)
    out += ['## Runs', '', *_runs_table(trends, label), '',
            '## Calibration epochs', '',
            'A new epoch starts when the calibration file in force changes (the positioner\'s '
            'diagnostics) or at a calibration run recorded in a bag. Only epochs with an '
            'observation are listed.', '', *_epochs_table(trends.epochs, label), '']
    if trends.series:
        out += ['## Accuracy and repeatability per mode and pose', '',
                *_pose_summary(trends.series), '']
        for mode in trends.modes:
            out += [f'### {mode}: AP_p ± U µm per run', '',
                    *_per_run(trends, mode, label,
                              lambda s, k: um_u(float(s.ap_p[k]), float(s.ap_p_u[k]))), '',
                    f'### {mode}: RP_l ± U µm per run', '',
                    *_per_run(trends, mode, label,
                              lambda s, k: um_u(_value(s.rp_l[k]), float(s.rp_l_u[k]))), '',
                    f'### {mode}: visits that conform / are indeterminate / do not conform '
                    'per run', '',
                    *_per_run(trends, mode, label, lambda s, k: decided(
                        dict(zip(DECISION_KEYS, s.decisions[k].tolist(), strict=True)))), '',
                    f'### {mode}: drift |Δ| µm since calibration (epoch)', '',
                    *_per_run(trends, mode, label, _drift_cell), '']
        out += ['## Drift since calibration', '',
                'Per epoch, mode and pose: the barycentre of the attained positions and the '
                'mean attained angles against those of the pose\'s first run in the epoch.',
                '', *_drift_table(trends), '']
    out += ['## Tracker registrations', '']
    if trends.registrations.time.size:
        out += _registrations_table(trends, label)
    else:
        out += ['No registration of the tracker on the base targets is recorded in these '
                'bags.']
    out.append('')
    if plots:
        out += ['## Plots', '', *(f'![{p.stem}]({p.name})' for p in plots), '']
    return '\n'.join(out)


def summary(trends: Trends, failures: Sequence[BagFailure] = (),
            plots: Sequence[Path] = ()) -> dict[str, Any]:
    """The JSON document (SI: m, rad, s; NaN as null)."""
    return {**trends.to_dict(), 'failed': [f.__dict__ for f in failures],
            'plots': [p.name for p in plots]}


def write_report(trends: Trends, out_dir: Path, failures: Sequence[BagFailure] = (),
                 plots: Sequence[Path] = ()) -> tuple[Path, Path]:
    """Write ``trends.md`` and ``trends.json`` into ``out_dir`` (created); their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md = out_dir / TRENDS_REPORT_FILE
    md.write_text(markdown(trends, failures, plots), encoding='utf-8')
    js = out_dir / TRENDS_SUMMARY_FILE
    js.write_text(json.dumps(summary(trends, failures, plots)), encoding='utf-8')
    return md, js


# -- plots -----------------------------------------------------------------------------------
def _dates(time: FloatArray) -> NDArray[np.datetime64]:
    """Log times (s since the Unix epoch) as datetime64 (µs) for a date axis."""
    return np.round(np.asarray(time, dtype=float) * 1e6).astype('int64').astype('datetime64[us]')


def _date_axis(ax: Any) -> None:
    """A date axis (UTC; matplotlib's automatic date ticks) with a light grid."""
    ax.tick_params(axis='x', labelsize=7, labelrotation=15)
    ax.grid(True, alpha=0.3)


#: A panel of a per-mode plot: title, y label, and the values of a series (R,) to draw.
Panel = tuple[str, str, Callable[[PoseSeries], FloatArray]]


def _per_mode_plot(trends: Trends, path: Path, title: str, panels: Sequence[Panel],
                   epochs: bool = False) -> Path:
    """A row per mode, a column per panel; a line per pose (one colour per pose across the
    figure) over the runs' time; with ``epochs`` each epoch's start a dashed line."""
    modes = trends.modes
    fig, axes = figure(6.0 * len(panels), 1.0 + 2.6 * len(modes), len(modes), len(panels),
                       sharex=True, margins=(0.07, 0.86, 0.92, 0.08), space=(0.22, 0.3))
    pose_colour = colours([p.name for p in trends.poses])
    starts = [e for e in trends.epochs if e.start is not None]
    for row, mode in enumerate(modes):
        for col, (name, unit, values) in enumerate(panels):
            ax = axes[row, col]
            for s in trends.series:
                if s.mode != mode:
                    continue
                y = values(s)
                # With epochs, a line per epoch: drift does not carry over a calibration.
                parts = [s.epoch == k for k in np.unique(s.epoch)] if epochs else [
                    np.ones(s.time.size, dtype=bool)]
                for k, part in enumerate(parts):
                    ax.plot(_dates(s.time[part]), y[part], 'o-', ms=3, lw=1,
                            color=pose_colour[s.pose.name], label=None if k else s.pose.name)
            for e in starts if epochs else ():
                assert e.start is not None
                at = _dates(np.array([e.start]))[0]
                ax.axvline(at, color='0.4', ls='--', lw=0.8)
                ax.annotate(f' e{e.index}', (at, 0.97), xycoords=('data', 'axes fraction'),
                            fontsize=7, va='top', color='0.3')
            ax.set_title(f'{mode}: {name}', fontsize=9)
            ax.set_ylabel(unit)
            _date_axis(ax)
    for ax in axes[-1]:
        ax.set_xlabel('UTC')
    axes[0, -1].legend(fontsize=7, title='pose', loc='upper left', bbox_to_anchor=(1.01, 1.0))
    fig.suptitle(title, fontsize=10)
    return save(fig, path)


def plot_accuracy(trends: Trends, path: Path) -> Path:
    """Per mode: AP_p (µm) and the largest |AP_a|, |AP_b|, |AP_c| (°) of each pose over time."""
    return _per_mode_plot(trends, path, 'ISO 9283 pose accuracy per run', (
        ('AP_p', 'µm', lambda s: s.ap_p * UM),
        ('max |AP_a|, |AP_b|, |AP_c|', '°', lambda s: _angle_max(s.ap_angles) * DEG)))


def plot_repeatability(trends: Trends, path: Path) -> Path:
    """Per mode: RP_l (µm) and the largest RP_a, RP_b, RP_c half-width (°) of each pose over
    time (runs with fewer than two visits of a pose leave a gap)."""
    return _per_mode_plot(trends, path, 'ISO 9283 pose repeatability per run', (
        ('RP_l', 'µm', lambda s: s.rp_l * UM),
        ('max RP_a, RP_b, RP_c (±)', '°', lambda s: _angle_max(s.rp_angles) * DEG)))


def plot_drift(trends: Trends, path: Path) -> Path:
    """Per mode: the drift of each pose since its first run in the epoch: |Δ| of the
    barycentre (µm) and the largest mean angle change (°), epochs' starts dashed."""
    return _per_mode_plot(trends, path, 'Drift since calibration (dashed: a new epoch)', (
        ('|Δ barycentre|', 'µm', lambda s: s.drift_distance * UM),
        ('max |Δa|, |Δb|, |Δc|', '°', lambda s: _angle_max(s.drift_angles) * DEG)),
        epochs=True)


def plot_registrations(trends: Trends, path: Path) -> Path:
    """The tracker's registrations over time: residual RMS and max over the base targets (µm)
    and the variance factor."""
    r = trends.registrations
    fig, axes = figure(10, 6, 2, 1, sharex=True, margins=(0.08, 0.98, 0.92, 0.1),
                       space=(0.2, 0.15))
    t = _dates(r.time)
    axes[0, 0].plot(t, r.residual_rms * UM, 'o-', ms=3, label='RMS')
    axes[0, 0].plot(t, r.residual_max * UM, 's-', ms=3, label='max')
    axes[0, 0].set_ylabel('residual µm')
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].plot(t, r.variance_factor, 'o-', ms=3, color='C2')
    axes[1, 0].set_ylabel('variance factor')
    for ax in axes[:, 0]:
        _date_axis(ax)
    axes[1, 0].set_xlabel('UTC')
    fig.suptitle('Tracker registration on the base targets', fontsize=10)
    return save(fig, path)


def write_plots(trends: Trends, out_dir: Path) -> list[Path]:
    """The plots that have something to show into ``out_dir`` (created); their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    if trends.series:
        paths += [plot_accuracy(trends, out_dir / 'trend_accuracy.png'),
                  plot_repeatability(trends, out_dir / 'trend_repeatability.png'),
                  plot_drift(trends, out_dir / 'trend_drift.png')]
    if trends.registrations.time.size:
        paths.append(plot_registrations(trends, out_dir / 'trend_registrations.png'))
    return paths
