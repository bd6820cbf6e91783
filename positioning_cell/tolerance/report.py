"""The report of a tolerance analysis (:class:`.analysis.Analysis`): Markdown for people, JSON
(SI) for programs, and per assembly dimension a Pareto chart of the sources' contributions and
the sampled distribution against the requirement (:mod:`positioning_cell.plotting`).

People read lengths in the file's unit and angles in degrees; sensitivities in output unit per
source unit (``mm/deg``); the matrices A, U, C, D, T in the file's length unit and radians,
as seed 004 prints them. Every file is written whole (a temporary file renamed over it).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import plotting
from positioning_cell.tolerance.analysis import Analysis, DimensionResult
from positioning_cell.tolerance.expressions import ANGLE, LENGTH
from positioning_cell.tolerance.model import Mechanism
from positioning_cell.tolerance.stackup import YieldEstimate

FloatArray = NDArray[np.float64]
#: Sources shown in a Pareto chart (the rest are summed in the table only).
PARETO_BARS = 20


def _si_scale(mech: Mechanism, dim: str) -> float:
    """SI per matrix unit: the file's length unit, or 1 rad."""
    return mech.length_scale if dim == LENGTH else 1.0


def matrix_in_file_units(mech: Mechanism, matrix: FloatArray, row_dims: tuple[str, ...],
                         col_dims: tuple[str, ...]) -> FloatArray:
    """A derivative matrix (SI) in the file's length unit and radians (∂row/∂col)."""
    rows = np.array([_si_scale(mech, d) for d in row_dims])
    cols = np.array([_si_scale(mech, d) for d in col_dims])
    out: FloatArray = matrix * cols[None, :] / rows[:, None]
    return out


def _q(mech: Mechanism, value: float, dim: str, digits: int = 5) -> str:
    """A SI value in the report's unit, with the unit."""
    if not math.isfinite(value):
        return 'n/a'
    if abs(value) < 1e-12:   # below the closure tolerance: rounding, shown as 0
        value = 0.0
    return f'{mech.display(value, dim):.{digits}g} {mech.unit(dim)}'


def _per(mech: Mechanism, value: float, out_dim: str, src_dim: str) -> str:
    """A sensitivity (SI) in output unit per source unit."""
    shown = value / _display_scale(mech, out_dim) * _display_scale(mech, src_dim)
    return f'{shown + 0.0:.6g} {mech.unit(out_dim)}/{mech.unit(src_dim)}'


def _display_scale(mech: Mechanism, dim: str) -> float:
    """SI per display unit (the file's length unit, or 1°)."""
    return mech.length_scale if dim == LENGTH else math.pi / 180.0


def _percent(p: float) -> str:
    """A probability in per cent, with the digits that tell 99.999 % from 100 %."""
    return f'{100 * p:.{3 if p < 0.999 else 5}f}'


def _yield(y: YieldEstimate | None) -> str:
    if y is None:
        return '—'
    return (f'{_percent(y.probability)} % [{_percent(y.low)}, {_percent(y.high)}] '
            f'({y.inside}/{y.trials})')


def _requirement(mech: Mechanism, d: DimensionResult) -> str:
    req = d.loop.requirement
    if req is None or d.band is None:
        return '—'
    dim = d.loop.dimension
    ref = d.nominal if req.nominal is None else req.nominal
    lo, hi = ref + req.lower, ref + req.upper
    return f'{_q(mech, lo, dim)} … {_q(mech, hi, dim)}'


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    out += ['| ' + ' | '.join(r) + ' |' for r in rows]
    return out + ['']


def _matrix(title: str, matrix: FloatArray, rows: tuple[str, ...],
            cols: tuple[str, ...]) -> list[str]:
    if matrix.size == 0:
        return []
    # Entries below 1e-12 of the largest are rounding (cos 90° = 6e-17): shown as 0.
    shown = np.where(np.abs(matrix) > 1e-12 * np.abs(matrix).max(), matrix, 0.0) + 0.0
    return [f'**{title}**', '', *_table(['', *cols], [
        [r, *(f'{v:.6g}' for v in row)] for r, row in zip(rows, shown, strict=True)])]


def slug(name: str) -> str:
    """A file-name-safe form of a dimension's name."""
    return re.sub(r'[^A-Za-z0-9_-]+', '_', name).strip('_') or 'dimension'


def markdown(analysis: Analysis, figures: dict[str, list[str]] | None = None) -> str:
    """The report as Markdown; ``figures`` (dimension name → file names) are linked."""
    mech, form = analysis.mechanism, analysis.form
    e, s = form.n_closure, form.n_sources
    lines = [f'# Tolerance analysis: {mech.name}', '',
             f'File `{mech.origin}`: {mech.space}, lengths in {mech.length_unit}, angles in '
             f'degrees; {len(mech.sources)} sources, {len(mech.unknowns)} unknowns, '
             f'{len(mech.open_loops)} assembly dimensions (seed 004 vector loops).', '']
    if mech.description:
        lines += [mech.description.strip(), '']
    if analysis.refusal is not None:
        lines += ['## Refused', '', f'**The analysis is refused**: {analysis.refusal}.', '',
                  'No sensitivity, stack-up or yield is given for a mechanism whose closed '
                  'loops do not fix its unknowns (or do not close).', '']
    else:
        lines += ['## Summary', '']
        lines += _table(
            ['dimension', 'nominal', 'requirement', 'worst case (eq. 15)', 'RSS',
             'linear ±3σ', 'Monte Carlo 0.135…99.865 %', f'yield ({analysis.confidence:.0%} '
             'Wilson interval)', 'yield, linear model'],
            [[d.loop.name, _q(mech, d.nominal, d.loop.dimension), _requirement(mech, d),
              '± ' + _q(mech, d.worst_case, d.loop.dimension),
              '± ' + _q(mech, d.rss, d.loop.dimension),
              '± ' + _q(mech, 3 * d.linear_std, d.loop.dimension),
              (f'{_q(mech, d.sampled.low, d.loop.dimension)} … '
               f'{_q(mech, d.sampled.high, d.loop.dimension)}') if d.sampled else '—',
              _yield(d.yield_nonlinear), _yield(d.yield_linear)]
             for d in analysis.dimensions])
        mc = analysis.monte_carlo
        if mc is not None and mc.joint_yield is not None:
            lines += [f'All requirements together: {_yield(mc.joint_yield)}.', '']
    lines += _nominal_section(analysis)
    lines += ['## Sources', '']
    lines += _table(['source', 'nominal', '± tolerance', 'law', 'σ', 'from'],
                    [[src.name, _q(mech, src.nominal, src.dimension),
                      _q(mech, src.tolerance, src.dimension),
                      src.distribution + (f' (±{src.sigmas:g}σ)'
                                          if src.distribution == 'normal' else ''),
                      _q(mech, src.std, src.dimension), src.origin or '—']
                     for src in mech.sources])
    if mech.gaps:
        lines += ['## Gap connectors (seed 004 §2)', '']
        values = {**{i.name: i.value for i in mech.inputs},
                  **{x.name: x.nominal for x in mech.sources},
                  **dict(zip(mech.unknown_names, (analysis.linearisation.u0
                                                  if analysis.linearisation else form.guess),
                             strict=True))}
        lines += _table(['gap', 'clearance', 'α at the nominal', 'rule'],
                        [[g.name, _q(mech, g.length.evaluate(values), LENGTH),
                          _q(mech, g.alpha.evaluate(values), ANGLE), g.rule]
                         for g in mech.gaps])
    for d in analysis.dimensions:
        lines += _dimension_section(analysis, d, (figures or {}).get(d.loop.name, []))
    lines += _matrices_section(analysis, e, s)
    lines += _monte_carlo_section(analysis)
    if analysis.derivatives is not None:
        c = analysis.derivatives
        lines += ['## Derivatives', '',
                  f'Analytic against central differences at the nominal solution: largest '
                  f'difference {c.max_abs:.3g} (SI), largest relative {c.max_rel:.3g} '
                  f'({c.row}, ∂/∂{c.symbol}).', '']
    return '\n'.join(lines)


def _nominal_section(analysis: Analysis) -> list[str]:
    mech, form, lin = analysis.mechanism, analysis.form, analysis.linearisation
    e = form.n_closure
    lines = ['## Nominal state', '']
    rows = []
    for j, u in enumerate(mech.unknowns):
        solved = _q(mech, float(lin.u0[j]), u.dimension, 9) if lin else '—'
        rows.append([u.name, _q(mech, u.guess, u.dimension, 9), solved])
    lines += _table(['unknown', 'given', 'solved (the nominal)'], rows)
    lines += ['Closure residual at the given values (before solving):', '']
    lines += _table(['equation', 'h'],
                    [[name, _q(mech, float(v), dim)] for name, v, dim in zip(
                        form.rows[:e], analysis.guess_residual, form.row_dimensions[:e],
                        strict=True)])
    if lin is not None:
        lines += [f'Newton steps to the nominal solution: {lin.iterations}; condition number '
                  f'of U there: {lin.condition:.4g}.', '']
    return lines


def _dimension_section(analysis: Analysis, d: DimensionResult, figures: list[str]) -> list[str]:
    mech = analysis.mechanism
    dim = d.loop.dimension
    c = d.contributions
    lines = [f'## {d.loop.name}: sensitivities and contributions', '',
             f'Nominal {_q(mech, d.nominal, dim, 9)}; worst case ± {_q(mech, d.worst_case, dim)}'
             f' (Σ|T_i|·t_i, seed 004 eq. 15), RSS ± {_q(mech, d.rss, dim)}, linear σ '
             f'{_q(mech, d.linear_std, dim)}.', '']
    rows = []
    for rank, (i, worst, share, cum, var) in enumerate(zip(
            c.order, c.worst, c.share, c.cumulative, c.variance, strict=True)):
        src = mech.sources[int(i)]
        rows.append([str(rank + 1), src.name, _per(mech, float(d.sensitivity[i]), dim,
                                                   src.dimension),
                     '± ' + _q(mech, src.tolerance, src.dimension),
                     _q(mech, float(worst), dim), f'{100 * share:.2f} %', f'{100 * cum:.2f} %',
                     f'{100 * var:.2f} %'])
    lines += _table(['#', 'source', 'sensitivity T', 'tolerance', r'\|T\|·t', 'share',
                     'cumulative', 'share of variance'], rows)
    lines += [f'![{f}]({f})' for f in figures] + ([''] if figures else [])
    return lines


def _matrices_section(analysis: Analysis, e: int, s: int) -> list[str]:
    mech, form, lin = analysis.mechanism, analysis.form, analysis.linearisation
    if len(form.symbols) > 60:
        return []
    rd, cd = form.row_dimensions, form.dimensions
    src, unk = form.symbols[:s], form.symbols[s:]
    eqs, outs = form.rows[:e], form.rows[e:]

    def conv(m: FloatArray, rows: tuple[str, ...], cols: tuple[str, ...]) -> FloatArray:
        return matrix_in_file_units(mech, m, rows, cols)

    b = analysis.at_guess if lin is None else lin
    where = 'at the given nominal' if lin is None else 'at the nominal solution'
    lines = [f'## First-order matrices {where} (seed 004 eqs. 9-14; {mech.length_unit} and '
             'rad)', '']
    lines += _matrix('A = ∂h/∂x', conv(b.A, rd[:e], cd[:s]), eqs, src)
    lines += _matrix('U = ∂h/∂u', conv(b.U, rd[:e], cd[s:]), eqs, unk)
    lines += _matrix('C = ∂Gap/∂x', conv(b.C, rd[e:], cd[:s]), outs, src)
    lines += _matrix('D = ∂Gap/∂u', conv(b.D, rd[e:], cd[s:]), outs, unk)
    if lin is not None:
        lines += _matrix('T = C − D·U⁻¹·A', conv(lin.T, rd[e:], cd[:s]), outs, src)
    else:
        sv = np.linalg.svd(b.U, compute_uv=False)
        lines += [f'Singular values of U: {", ".join(f"{v:.4g}" for v in sv)}.', '']
    return lines


def _monte_carlo_section(analysis: Analysis) -> list[str]:
    mech, mc = analysis.mechanism, analysis.monte_carlo
    if mc is None:
        return []
    rate = mc.samples / mc.seconds if mc.seconds > 0 else float('inf')
    lines = ['## Monte Carlo (nonlinear loop closure)', '',
             f'{mc.samples} samples (seed {mc.seed}), {mc.unsolved} unsolved (counted outside '
             f'every requirement); Newton steps per sample: mean {mc.mean_iterations:.2f}, max '
             f'{mc.max_iterations}; {mc.seconds:.2f} s ({rate:,.0f} samples/s, draws included).',
             '']
    rows = []
    for d in analysis.dimensions:
        st, dim = d.sampled, d.loop.dimension
        if st is None:
            continue
        rows.append([d.loop.name, _q(mech, st.mean, dim), _q(mech, st.std, dim),
                     _q(mech, st.linear_std, dim), _q(mech, st.minimum, dim),
                     _q(mech, st.maximum, dim), _q(mech, st.nonlinearity, dim)])
    lines += ['Deviations from the nominal:', '']
    lines += _table(['dimension', 'mean', 'σ', 'σ of T·x', 'min', 'max',
                     r'max \|nonlinear − T·x\|'], rows)
    return lines


def _yield_json(y: YieldEstimate | None) -> dict[str, Any] | None:
    if y is None:
        return None
    return {'inside': y.inside, 'trials': y.trials, 'probability': y.probability,
            'low': y.low, 'high': y.high, 'confidence': y.confidence}


def as_json(analysis: Analysis) -> dict[str, Any]:
    """The analysis as a JSON-able dict, SI (m, rad)."""
    mech, form, lin = analysis.mechanism, analysis.form, analysis.linearisation
    e = form.n_closure
    out: dict[str, Any] = {
        'mechanism': mech.name, 'file': mech.origin, 'units': 'SI (m, rad)',
        'refusal': analysis.refusal,
        'sources': [{'name': x.name, 'dimension': x.dimension, 'nominal': x.nominal,
                     'tolerance': x.tolerance, 'distribution': x.distribution,
                     'sigmas': x.sigmas, 'std': x.std} for x in mech.sources],
        'unknowns': [{'name': u.name, 'dimension': u.dimension, 'guess': u.guess,
                      'nominal': float(lin.u0[j]) if lin else None}
                     for j, u in enumerate(mech.unknowns)],
        'equations': list(form.rows[:e]),
        'guess_residual': analysis.guess_residual.tolist(),
        'at_guess': {k: getattr(analysis.at_guess, k).tolist() for k in 'AUCD'},
    }
    if lin is not None:
        out['linearisation'] = {
            'A': lin.A.tolist(), 'U': lin.U.tolist(), 'C': lin.C.tolist(),
            'D': lin.D.tolist(), 'T': lin.T.tolist(), 'condition': lin.condition,
            'iterations': lin.iterations, 'method': lin.method}
    out['dimensions'] = [{
        'name': d.loop.name, 'dimension': d.loop.dimension, 'nominal': d.nominal,
        'band': list(d.band) if d.band else None, 'sensitivity': d.sensitivity.tolist(),
        'worst_case': d.worst_case, 'rss': d.rss, 'linear_std': d.linear_std,
        'contributions': {'order': [mech.sources[int(i)].name for i in d.contributions.order],
                          'worst': d.contributions.worst.tolist(),
                          'share': d.contributions.share.tolist(),
                          'variance': d.contributions.variance.tolist()},
        'sampled': None if d.sampled is None else vars(d.sampled),
        'yield': _yield_json(d.yield_nonlinear), 'yield_linear': _yield_json(d.yield_linear),
    } for d in analysis.dimensions]
    mc = analysis.monte_carlo
    out['monte_carlo'] = None if mc is None else {
        'samples': mc.samples, 'seed': mc.seed, 'unsolved': mc.unsolved,
        'mean_iterations': mc.mean_iterations, 'max_iterations': mc.max_iterations,
        'seconds': mc.seconds, 'joint_yield': _yield_json(mc.joint_yield)}
    d_check = analysis.derivatives
    out['derivatives'] = None if d_check is None else vars(d_check)
    return out


def plot_pareto(analysis: Analysis, d: DimensionResult, path: Path) -> Path:
    """Bars: each source's worst-case contribution |T_i|·t_i (largest first, at most
    :data:`PARETO_BARS`); line: the cumulative share."""
    mech = analysis.mechanism
    c = d.contributions
    k = min(PARETO_BARS, c.order.size)
    names = [mech.sources[int(i)].name for i in c.order[:k]]
    values = [mech.display(float(v), d.loop.dimension) for v in c.worst[:k]]
    fig, axes = plotting.figure(max(6.0, 0.45 * k + 2.0), 4.2, margins=(0.1, 0.9, 0.9, 0.22))
    ax = axes[0, 0]
    colour = plotting.colours(['bars', 'line'])
    ax.bar(range(k), values, color=colour['bars'])
    ax.set_xticks(range(k), names, rotation=60, ha='right')
    ax.set_ylabel(f'|T_i|·t_i ({mech.unit(d.loop.dimension)})')
    twin = ax.twinx()
    twin.plot(range(k), 100 * c.cumulative[:k], 'o-', color=colour['line'])
    twin.set_ylim(0, 105)
    twin.set_ylabel('cumulative share of the worst case (%)')
    ax.set_title(f'{d.loop.name}: contributions (worst case ± '
                 f'{_q(mech, d.worst_case, d.loop.dimension)})')
    return _save(fig, path)


def plot_distribution(analysis: Analysis, d: DimensionResult, index: int, path: Path) -> Path:
    """Histogram of the sampled deviations (nonlinear closure and T·x), the requirement's
    limits and ± the worst case."""
    mech, mc = analysis.mechanism, analysis.samples
    assert mc is not None
    dim = d.loop.dimension
    scale = _display_scale(mech, dim)
    nonlinear = mc.outputs[:, index]
    nonlinear = nonlinear[np.isfinite(nonlinear)] / scale
    linear = mc.linear[:, index] / scale
    fig, axes = plotting.figure(7.0, 4.2, margins=(0.1, 0.97, 0.9, 0.13))
    ax = axes[0, 0]
    colour = plotting.colours(['nonlinear', 'linear', 'limit', 'worst'])
    ax.hist(nonlinear, bins=120, density=True, color=colour['nonlinear'], alpha=0.6,
            label='nonlinear closure')
    ax.hist(linear, bins=120, density=True, histtype='step', color=colour['linear'],
            label='linear model T·x')
    for v in (-d.worst_case / scale, d.worst_case / scale):
        ax.axvline(v, color=colour['worst'], ls=':', label=None)
    if d.band is not None:
        for v in d.band:
            ax.axvline(v / scale, color=colour['limit'], ls='--')
    ax.set_xlabel(f'deviation from the nominal ({mech.unit(dim)}); dashed: requirement, '
                  'dotted: ± worst case')
    ax.set_ylabel('density')
    ax.legend(loc='upper right', fontsize='small')
    ax.set_title(f'{d.loop.name}: {mc.outputs.shape[0]} samples')
    return _save(fig, path)


def _save(fig: Any, path: Path) -> Path:
    tmp = path.with_name(f'.{path.stem}.tmp{path.suffix}')
    plotting.save(fig, tmp)
    os.replace(tmp, path)
    return path


def _write(path: Path, text: str) -> Path:
    tmp = path.with_name(f'.{path.name}.tmp')
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def write_report(analysis: Analysis, out_dir: Path, *, plots: bool = True) -> tuple[Path, ...]:
    """Write ``report.md``, ``analysis.json`` and (``plots``) the figures into ``out_dir``
    (created); returns the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    figures: dict[str, list[str]] = {}
    if plots:
        for g, d in enumerate(analysis.dimensions):
            name = slug(d.loop.name)
            made = [plot_pareto(analysis, d, out_dir / f'pareto_{name}.png')]
            if analysis.samples is not None:
                made.append(plot_distribution(analysis, d, g,
                                              out_dir / f'distribution_{name}.png'))
            figures[d.loop.name] = [p.name for p in made]
            files += made
    files.append(_write(out_dir / 'report.md', markdown(analysis, figures)))
    files.append(_write(out_dir / 'analysis.json',
                        json.dumps(as_json(analysis), indent=1, allow_nan=True)))
    return tuple(files)


def summary(analysis: Analysis) -> str:
    """A few lines for the console."""
    mech = analysis.mechanism
    if analysis.refusal is not None:
        return f'{mech.name}: refused: {analysis.refusal}\n'
    lines = [f'{mech.name}: {len(mech.sources)} sources, {len(mech.unknowns)} unknowns']
    for d in analysis.dimensions:
        dim = d.loop.dimension
        line = (f'  {d.loop.name}: nominal {_q(mech, d.nominal, dim, 8)}, worst case ± '
                f'{_q(mech, d.worst_case, dim)}, RSS ± {_q(mech, d.rss, dim)}')
        if d.yield_nonlinear is not None:
            line += f', yield {_yield(d.yield_nonlinear)}'
        lines.append(line)
    mc = analysis.monte_carlo
    if mc is not None:
        lines.append(f'  Monte Carlo: {mc.samples} samples, {mc.unsolved} unsolved, '
                     f'{mc.seconds:.2f} s')
    return '\n'.join(lines) + '\n'
