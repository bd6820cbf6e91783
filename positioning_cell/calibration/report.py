"""The calibration report: validation on hold-out poses and the Markdown summary with plots.

Validation compares, at each measured pose, the pose the tracker measured with the pose a
model predicts from the encoder readings there: the nominal machine (what an uncalibrated cell
believes) and the calibrated one. Poses of the fit and hold-out poses never used in it are
shown apart; only the hold-out figures say how well the model predicts.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.identify import CalibrationData, Identification
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.calibration.observability import Indices
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import pose_error
from positioning_cell.plotting import figure, save

FloatArray = NDArray[np.float64]


class Prediction(NamedTuple):
    """Measured minus predicted pose per pose: position (N, 3) m, rotation vector (N, 3) rad,
    for the ``nominal`` machine and the ``calibrated`` one."""

    nominal: tuple[FloatArray, FloatArray]
    calibrated: tuple[FloatArray, FloatArray]


def predict(nominal: Mechanism, model: MachineModel, data: CalibrationData) -> Prediction:
    """How well each machine predicts the measured poses of ``data`` from their encoder
    readings under their recorded conditions (module docstring)."""
    out = []
    conditions = Conditions(data.temperature, data.approach)
    for machine in (MachineModel(nominal), model):
        pose = machine.poses(data.joints[:, :3], data.joints[:, 3:], conditions=conditions)
        out.append(pose_error(data.position, data.quaternion, pose.position, pose.quaternion))
    return Prediction(out[0], out[1])


def _rms(a: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.sum(a**2, axis=1)))) if a.size else float('nan')


#: How the report shows each unit: (shown unit, factor).
_SHOWN = {'m': ('um', 1e6), 'rad': ('urad', 1e6), 'm/N': ('nm/N', 1e9),
          'rad/(N m)': ('urad/(N m)', 1e6), '1/K': ('ppm/K', 1e6), '1': ('ppm', 1e6)}


def _shown_unit(unit: str) -> tuple[str, float]:
    return _SHOWN.get(unit, (unit, 1.0))


def summary_lines(label: str, prediction: Prediction) -> list[str]:
    """Markdown table rows: RMS and max |Δp| (µm) and RMS angle (µrad), nominal vs calibrated."""
    rows = []
    for name, (e_p, e_r) in (('nominal', prediction.nominal),
                             ('calibrated', prediction.calibrated)):
        norm = np.linalg.norm(e_p, axis=1)
        rows.append(f'| {label} | {name} | {len(norm)} | {_rms(e_p) * 1e6:.2f} | '
                    f'{(norm.max() if norm.size else float("nan")) * 1e6:.2f} | '
                    f'{_rms(e_r) * 1e6:.1f} |')
    return rows


def observability_lines(indices: dict[str, Indices]) -> list[str]:
    """A Markdown table of observability indices, a column per set of parameters (each
    :class:`Indices`: :mod:`positioning_cell.calibration.observability`)."""
    if not indices:
        return []
    names = ('rows', 'columns', 'sigma_min', 'sigma_max', 'condition', 'o1', 'o2', 'o4')
    words = ('rows (measurements)', 'columns (parameters)', 'smallest singular value (O3)',
             'largest singular value', 'condition number', 'O1 (Borm & Menq)',
             'O2 (1 / condition)', 'O4 (noise amplification)')
    lines = ['| index | ' + ' | '.join(indices) + ' |', '|---|' + '---|' * len(indices)]
    for name, word in zip(names, words, strict=True):
        lines.append(f'| {word} | ' + ' | '.join(f'{getattr(ind, name):.4g}'
                                                 for ind in indices.values()) + ' |')
    return lines


def write_report(folder: Path, result: Identification, fit: Prediction,
                 hold_out: Prediction | None, title: str = 'Calibration',
                 indices: dict[str, Indices] | None = None,
                 production: list[str] | None = None,
                 verdicts: list[str] | None = None) -> Path:
    """``folder/calibration_report.md`` with ``calibration_errors.png`` and
    ``calibration_singular_values.png``; returns the Markdown path. ``indices``: the
    observability indices of the program measured (a column per set of parameters);
    ``production``: lines on what the calibration predicts at the production poses;
    ``verdicts``: the adequacy tests' lines, fit and hold-out (default: the fit's)."""
    folder.mkdir(parents=True, exist_ok=True)
    sets = [('fit', fit)] + ([('hold-out', hold_out)] if hold_out is not None else [])
    fig, axes = figure(6 * len(sets), 3.5, 1, len(sets), constrained=True)
    for ax, (label, pred) in zip(axes[0], sets, strict=True):
        for name, (e_p, _) in (('nominal', pred.nominal), ('calibrated', pred.calibrated)):
            ax.plot(np.linalg.norm(e_p, axis=1) * 1e6, 'o-', ms=3, label=name)
        ax.set_yscale('log')
        ax.set_xlabel(f'{label} pose')
        ax.set_ylabel('|measured - predicted| position, um')
        ax.legend()
        ax.grid(True, which='both', alpha=0.3)
    save(fig, folder / 'calibration_errors.png')
    fig, grid = figure(6, 3.5, constrained=True)
    ax = grid[0, 0]
    ax.semilogy(result.identifiability.singular_values, 'o-')
    ax.set_xlabel('index')
    ax.set_ylabel('singular value (scaled, whitened)')
    ax.grid(True, which='both', alpha=0.3)
    save(fig, folder / 'calibration_singular_values.png')
    ident = result.identifiability
    lines = [f'# {title}', '',
             f'{ident.rank} of {cp.COUNT} parameters identified from {len(fit.nominal[0])} '
             f'poses; chi2 {result.chi2:.1f} for {result.dof} degrees of freedom '
             f'(chi2/dof {result.chi2 / result.dof:.2f}).', '',
             '## Prediction of the measured poses', '',
             '| set | model | poses | RMS dp um | max dp um | RMS angle urad |',
             '|---|---|---|---|---|---|']
    for label, pred in sets:
        lines += summary_lines(label, pred)
    if verdicts is None:
        verdicts = [result.adequacy.verdict()] if result.adequacy is not None else []
    if verdicts:
        lines += ['', '## Model adequacy', '', *(f'- {v}' for v in verdicts)]
    lines += ['', '![errors](calibration_errors.png)', '', '## Parameters', '',
              '| parameter | value | sigma | unit |', '|---|---|---|---|']
    for k, name in enumerate(cp.PARAMETER_NAMES):
        unit, factor = _shown_unit(cp.UNITS[k])
        sigma = result.sigma[k]
        value = f'{result.x[k] * factor:.2f}' if ident.identified[k] else 'fixed at 0'
        lines.append(f'| {name} | {value} | '
                     f'{"" if np.isnan(sigma) else f"{sigma * factor:.2f}"} | {unit} |')
    if ident.merged:
        lines += ['', '## Not separable or not excited (fixed at 0)', '']
        lines += [f'- {name}: ' + (result.excluded.get(name) or 'absorbed by ' + (
            ', '.join(f'{p} ({c:+.2f})' for p, c in partners)
            or 'nothing (too little effect on the data)'))
            for name, partners in ident.merged.items()]
    lines += ['', '## Identifiability', '',
              'Singular values of the whitened Jacobian in units of each parameter\'s expected '
              'size: ' + ', '.join(f'{v:.3g}' for v in ident.singular_values) + '.', '',
              '![singular values](calibration_singular_values.png)', '']
    if indices:
        lines += ['## Observability of the program measured', '',
                  'Indices of the scaled whitened identification Jacobian of the fit poses '
                  '(positioning_cell.calibration.observability; larger is better except the '
                  'condition number).', '', *observability_lines(indices), '']
    if production:
        lines += ['## At the production poses', '', *production, '']
    path = folder / 'calibration_report.md'
    path.write_text('\n'.join(lines))
    return path
