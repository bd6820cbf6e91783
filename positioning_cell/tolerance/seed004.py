"""Seed 004 §4's printed numbers, checked: which of them follow from what.

The paper prints, for its inner-flap linkage (mm and rad; sources x = a1…a9, b, r12, r23,
r34, r56, the order that reproduces A and C column by column; unknowns u1, u2, u3), the
matrices A (3 × 14), U (3 × 3), C, D, the sensitivity T, the worst case ± 6.24 mm (eq. 15),
and Monte Carlo yields against 285 ± 5 mm of 86.105 % (with clearance) and 99.972 % (without).
This module takes them as printed (:data:`PRINTED`) and finds:

- U is singular: its u2 and u3 columns are identical (det 0 to the printed digits); the engine
  refuses it (:func:`.linear.check_closure`), naming u2, u3 and the three equations.
- T is C − D'·U'⁻¹·A' with U' the rows (h_y, h_θ) and the columns (u1, u2) of U: the paper
  dropped h_x and u3 (:func:`reproduce_t`).
- ± 6.24 mm is not Σ|T_i|·t_i of the printed T (16.65 mm, of which a7's misprinted column gives
  10.3 mm); it appears only if some tolerances are zeroed (:func:`worst_case_subsets`).
- No law gives 86.105 % or 99.972 % from the printed T (:func:`yield_hypotheses`): the
  clearance columns change the yield by less than 0.01 % (their tolerances are 0.01-0.02 mm).

``python -m positioning_cell.tolerance.seed004 [VARIANT.yaml]`` prints it all, and the
engine's figures for the variant file (examples/seed004_flap_variant.yaml) beside the paper's.
"""

from __future__ import annotations

import itertools
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm

from positioning_cell.errors import InputError, PositioningError
from positioning_cell.tolerance.expressions import ANGLE, LENGTH, Affine
from positioning_cell.tolerance.linear import SingularLoopsError, check_closure
from positioning_cell.tolerance.loops import Form, Linearisation, linearise
from positioning_cell.tolerance.model import Mechanism, Source, Vector
from positioning_cell.tolerance.sampling import draw
from positioning_cell.tolerance.stackup import estimate_yield, worst_case

FloatArray = NDArray[np.float64]

SOURCES = ('a1', 'a2', 'a3', 'a4', 'a5', 'a6', 'a7', 'a8', 'a9', 'b', 'r12', 'r23', 'r34',
           'r56')
UNKNOWNS = ('u1', 'u2', 'u3')
EQUATIONS = ('h_x', 'h_y', 'h_θ')
#: Table 1 and 2 tolerances, mm and rad (a8, b: ± 1°).
TOLERANCES = np.array([0.10, 0.30, 0.30, 0.30, 0.35, 0.35, 0.30, math.radians(1.0), 0.30,
                       math.radians(1.0), 0.01, 0.01, 0.02, 0.02])
CLEARANCES = ('r12', 'r23', 'r34', 'r56')
#: The requirement's half-width (285 ± 5 mm) and the paper's results.
REQUIREMENT = 5.0
PRINTED_WORST_CASE = 6.24
PRINTED_YIELD = 0.86105
PRINTED_YIELD_WITHOUT_CLEARANCE = 0.99972


@dataclass(frozen=True)
class Printed:
    """The matrices as printed (mm, rad): A (3, 14) (printed in two halves of 7 columns),
    U (3, 3), C (14,), D (3,), T (14,)."""

    A: FloatArray
    U: FloatArray
    C: FloatArray
    D: FloatArray
    T: FloatArray


PRINTED = Printed(
    A=np.array([[0, 0, 1, 0.105, 0, 0, 0.988, 33.594, 1, 0, 0, 0, 0.809, 0],
                [0, 0, 0, 0.995, 1, 1, 0.156, 217.943, 0, 0, 0, 0, 0.588, 1],
                [0, 0, 0, 0, 0, 0, 0, -1, 0, -1, 0, 0, 0, 0]], dtype=float),
    U=np.array([[-22.4, 0.995, 0.995], [-538.85, 0.104, 0.104], [1.0, 0.0, 0.0]]),
    C=np.array([1, 0.5, 0, 0.995, 0, 0, 34.476, 217.943, 0, 0, 0.5, 0.866, 0.588, 0],
               dtype=float),
    D=np.array([-389.6, 0.105, 0.0]),
    T=np.array([1, 0.5, 0, -0.013, -1.008, -1.008, 34.319, 152.583, 0, 154.405, 0.5, 0.866,
                0.002, -1.008]))


@dataclass(frozen=True)
class Closure:
    """The printed U: its condition number, determinant, and the engine's refusal."""

    condition: float
    determinant: float
    refusal: str


def printed_closure() -> Closure:
    """Check the printed U as the engine checks any U."""
    cond = float(np.linalg.cond(PRINTED.U))
    det = float(np.linalg.det(PRINTED.U))
    try:
        check_closure(PRINTED.U, EQUATIONS, UNKNOWNS, ' (seed 004 as printed)')
    except SingularLoopsError as err:
        return Closure(cond, det, str(err))
    raise AssertionError('the printed U passed the closure check')   # it cannot


@dataclass(frozen=True)
class Reproduction:
    """T from a square sub-system of the printed matrices: the equations (rows of U) and
    unknowns (columns) kept, the T obtained and its largest difference from the printed T (in
    the columns other than ``skip``) and in every column."""

    equations: tuple[str, ...]
    unknowns: tuple[str, ...]
    T: FloatArray
    max_difference: float
    differences: FloatArray


def reproduce_t() -> tuple[Reproduction, ...]:
    """T = C − D'·U'⁻¹·A' for every choice of two equations and two unknowns whose U' is
    invertible, best match to the printed T first."""
    out = []
    for rows in itertools.combinations(range(3), 2):
        for cols in itertools.combinations(range(3), 2):
            sub = PRINTED.U[np.ix_(rows, cols)]
            if abs(np.linalg.det(sub)) < 1e-9:
                continue
            t = PRINTED.C - PRINTED.D[list(cols)] @ np.linalg.solve(sub, PRINTED.A[list(rows)])
            diff = np.abs(t - PRINTED.T)
            out.append(Reproduction(tuple(EQUATIONS[r] for r in rows),
                                    tuple(UNKNOWNS[c] for c in cols), t, float(diff.max()),
                                    diff))
    return tuple(sorted(out, key=lambda r: r.max_difference))


@dataclass(frozen=True)
class WorstCases:
    """Σ|T_i|·t_i of the printed T: all sources, without a7, without the clearances; the
    zeroed-tolerance subsets within ``within`` mm of 6.24 (smallest first) and their count."""

    all_sources: float
    without_a7: float
    without_clearances: float
    without_a7_and_clearances: float
    hits: tuple[tuple[float, tuple[str, ...]], ...]
    within: float


def worst_case_subsets(within: float = 0.005) -> WorstCases:
    """Search every subset of sources whose tolerance, zeroed, brings the printed T's worst
    case to 6.24 ± ``within`` mm (2¹⁴ subsets)."""
    contrib = np.abs(PRINTED.T) * TOLERANCES
    masks = np.array(list(itertools.product((False, True), repeat=contrib.size)))   # zeroed
    totals = (~masks) @ contrib
    hit = np.flatnonzero(np.abs(totals - PRINTED_WORST_CASE) <= within)
    hits = sorted(((float(totals[i]), tuple(n for n, z in zip(SOURCES, masks[i], strict=True)
                                            if z)) for i in hit), key=lambda h: len(h[1]))
    a7 = np.array([n == 'a7' for n in SOURCES])
    gaps = np.array([n in CLEARANCES for n in SOURCES])

    def wc(keep: NDArray[np.bool_]) -> float:
        return float(worst_case(PRINTED.T[keep][None], TOLERANCES[keep])[0])

    every = np.ones(contrib.size, dtype=bool)
    return WorstCases(wc(every), wc(~a7), wc(~gaps), wc(~a7 & ~gaps), tuple(hits), within)


@dataclass(frozen=True)
class YieldHypothesis:
    """P(|T·x| ≤ 5 mm) under one hypothesis: ``label``, the Monte Carlo estimate and its
    Wilson interval, and the σ the linear model gives."""

    label: str
    probability: float
    low: float
    high: float
    sigma: float


def yield_hypotheses(samples: int = 400_000, seed: int = 4) -> tuple[YieldHypothesis, ...]:
    """The yield of the printed T against ± 5 mm, sampled, for each law (normal ± t = 3σ
    truncated, uniform ± t) with and without a7 and the clearances."""
    rng = np.random.default_rng(seed)
    out = []
    a7 = np.array([n == 'a7' for n in SOURCES])
    gaps = np.array([n in CLEARANCES for n in SOURCES])
    for law in ('normal', 'uniform'):
        sources = [Source(n, LENGTH, 0.0, float(t), law) for n, t in zip(
            SOURCES, TOLERANCES, strict=True)]
        x = draw(sources, samples, rng)
        for label, keep in (('all sources', ~np.zeros(14, dtype=bool)),
                            ('without clearances', ~gaps), ('without a7', ~a7),
                            ('without a7 and clearances', ~a7 & ~gaps)):
            gap = PRINTED.T[keep] @ x[keep]
            y = estimate_yield(np.abs(gap) <= REQUIREMENT)
            sigma = float(np.sqrt(np.sum((PRINTED.T[keep] * np.array(
                [s.std for s, k in zip(sources, keep, strict=True) if k])) ** 2)))
            out.append(YieldHypothesis(f'{law}, {label}', y.probability, y.low, y.high, sigma))
    return tuple(out)


def sigma_for(probability: float) -> float:
    """The σ (mm) of a centred normal law with P(|x| ≤ 5 mm) = ``probability``."""
    return REQUIREMENT / float(norm.ppf(0.5 + probability / 2.0))


def position_closure_variant(mech: Mechanism, loop: str = 'flap') -> Mechanism:
    """The other analysable choice: ``loop`` closed in x and y (no scalar equations), its
    vectors labelled ``ground…`` replaced by a constant ground vector that closes it at the
    nominal (the sources' nominals and the unknowns' starting values)."""
    target = next((c for c in mech.closed_loops if c.name == loop), None)
    if target is None:
        raise InputError(f'{mech.origin}: no closed loop {loop!r}')
    kept = tuple(v for v in target.vectors if not v.label.startswith('ground'))
    trial = replace(mech, closed_loops=tuple(
        replace(c, vectors=kept, components=('x', 'y'), equations=()) if c is target else c
        for c in mech.closed_loops))
    form = Form.from_mechanism(trial)
    start = sum(len(c.components) + len(c.equations) for c in mech.closed_loops
                if c is not target and mech.closed_loops.index(c) < mech.closed_loops.index(
                    target))
    h = form.evaluate(form.point())[start:start + 2]
    zero = Affine.zero(ANGLE)
    ground = (Vector(Affine((), -float(h[0]), LENGTH), zero, zero, 'ground x'),
              Vector(Affine((), -float(h[1]), LENGTH), Affine((), math.pi / 2.0, ANGLE), zero,
                     'ground y'))
    return replace(trial, name=f'{mech.name}, closed in x and y', closed_loops=tuple(
        replace(c, vectors=kept + ground, components=('x', 'y'), equations=())
        if c.name == loop else c for c in trial.closed_loops))


def _fmt(values: Iterable[float]) -> str:
    return ' '.join(f'{v:8.3f}' for v in values)


def report(variant: Linearisation | None = None, tolerances: FloatArray | None = None,
           alternative: Linearisation | None = None) -> str:
    """The findings as Markdown text; with the engine's linearisation of the variant (its
    sources a1…a9, b, u3, r12…r56 and their tolerances, SI), its T beside the printed T."""
    closure = printed_closure()
    lines = ['# Seed 004 §4: the printed numbers checked', '',
             f'Printed U: det = {closure.determinant:.3g}, condition number '
             f'{closure.condition:.3g}. Engine: {closure.refusal}.', '']
    reps = reproduce_t()
    best = reps[0]
    lines += [f'Printed T reproduced best by rows ({", ".join(best.equations)}) and unknowns '
              f'({", ".join(best.unknowns)}): largest difference {best.max_difference:.3f} '
              f'(column {SOURCES[int(np.argmax(best.differences))]}); other choices: ' + ', '.join(
                  f'({"/".join(r.equations)}; {"/".join(r.unknowns)}) {r.max_difference:.1f}'
                  for r in reps[1:]) + '.', '',
              '    source   ' + ' '.join(f'{n:>8}' for n in SOURCES),
              '    printed  ' + _fmt(PRINTED.T), '    rebuilt  ' + _fmt(best.T), '']
    wc = worst_case_subsets()
    lines += [f'Worst case Σ|T_i|·t_i of the printed T: {wc.all_sources:.3f} mm with every '
              f'source, {wc.without_a7:.3f} without a7, {wc.without_clearances:.3f} without '
              f'the clearances, {wc.without_a7_and_clearances:.3f} without both. Printed: '
              f'{PRINTED_WORST_CASE}. {len(wc.hits)} sets of zeroed tolerances give '
              f'{PRINTED_WORST_CASE} ± {wc.within}; the smallest: ' + '; '.join(
                  f'{{{", ".join(names)}}} {total:.4f}' for total, names in wc.hits[:4]) + '.',
              '']
    lines += ['Yield of the printed T against ± 5 mm (400 000 samples, 95 % Wilson interval):',
              '']
    lines += [f'- {h.label}: {100 * h.probability:.3f} % [{100 * h.low:.3f}, '
              f'{100 * h.high:.3f}], σ = {h.sigma:.3f} mm' for h in yield_hypotheses()]
    lines += ['', f'Printed: {100 * PRINTED_YIELD:.3f} % (needs σ = '
              f'{sigma_for(PRINTED_YIELD):.3f} mm for a centred normal law) and '
              f'{100 * PRINTED_YIELD_WITHOUT_CLEARANCE:.3f} % without clearance (σ = '
              f'{sigma_for(PRINTED_YIELD_WITHOUT_CLEARANCE):.3f} mm).', '']
    if variant is not None and tolerances is not None:
        lines += _variant_lines('Engine, variant (h_y, h_θ; u1, u2; u3 a source)', variant,
                                tolerances)
    if alternative is not None and tolerances is not None:
        lines += _variant_lines('Engine, alternative (h_x, h_y; u1, u2; u3 a source)',
                                alternative, tolerances)
    return '\n'.join(lines)


def _variant_lines(title: str, lin: Linearisation, tolerances: FloatArray) -> list[str]:
    """The engine's T (mm/mm, mm/rad) in the paper's column order, and its worst case."""
    t_mm = lin.T[0] * np.array([1.0 if n not in ('a8', 'b') else 1e3 for n in lin.sources])
    by_name = dict(zip(lin.sources, t_mm, strict=True))
    wc = float(worst_case(lin.T, tolerances)[0]) * 1e3
    extra = [n for n in lin.sources if n not in SOURCES]
    return [f'{title}: worst case ± {wc:.3f} mm; T in the paper\'s columns (mm/mm, '
            f'mm/rad)' + (f', plus {", ".join(extra)} ' + _fmt([by_name[n] for n in extra])
                          if extra else '') + ':', '',
            '    engine   ' + _fmt([by_name.get(n, math.nan) for n in SOURCES]),
            '    printed  ' + _fmt(PRINTED.T), '']


def main(argv: Sequence[str] | None = None) -> int:
    """Print the findings; with a variant mechanism file, the engine's figures too."""
    from positioning_cell.tolerance.model import load_mechanism

    args = list(sys.argv[1:] if argv is None else argv)
    default = Path(__file__).resolve().parents[2] / 'examples' / 'seed004_flap_variant.yaml'
    path = Path(args[0]) if args else default
    variant = alternative = None
    tolerances = None
    if path.is_file():
        try:
            mech = load_mechanism(path)
            variant = linearise(mech)
            alternative = linearise(position_closure_variant(mech))
            tolerances = np.array([s.tolerance for s in mech.sources])
        except PositioningError as err:
            print(f'seed004: error: {err}', file=sys.stderr)
            return 2
    print(report(variant, tolerances, alternative))
    return 0


if __name__ == '__main__':
    sys.exit(main())
