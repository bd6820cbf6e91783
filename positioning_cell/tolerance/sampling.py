"""Draws of the sources' deviations from their laws (seed 004 §3.2, the Monte Carlo step).

A source's law (:class:`~.model.Source`): ``normal`` with tolerance t = k·σ (k = ``sigmas``,
3 by default) truncated at ±t, drawn by rejection from ``rng.standard_normal`` (redrawing what
lies beyond k: exact, and far faster than ``scipy.stats.truncnorm.rvs``); ``uniform`` on ±t.
:func:`draw_laws` is the scheme itself (runs of sources with one law drawn in place into their
rows), which :func:`positioning_cell.prediction.sources.draw_sources` uses too.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import InputError
from positioning_cell.tolerance.model import Source

FloatArray = NDArray[np.float64]


def law_runs(sources: Sequence[Source]) -> tuple[tuple[int, int, str, float], ...]:
    """Runs of consecutive sources with the same law: (first, stop, law, sigmas), stop
    exclusive (sigmas 0 for a uniform law)."""
    runs: list[tuple[int, int, str, float]] = []
    for i, src in enumerate(sources):
        key = (src.distribution, src.sigmas if src.distribution == 'normal' else 0.0)
        if runs and runs[-1][2:] == key:
            runs[-1] = (runs[-1][0], i + 1, *key)
        else:
            runs.append((i, i + 1, *key))
    return tuple(runs)


def draw_laws(bounds: FloatArray, runs: Sequence[tuple[int, int, str, float]], n: int,
              rng: np.random.Generator) -> FloatArray:
    """n deviations (S, n), C-ordered (samples contiguous per source), of sources with
    half-widths ``bounds`` (S,) and laws in ``runs`` (first, stop, law, sigmas: a normal law
    with bound = sigmas·σ truncated there, or ``uniform`` on ±bound), drawn run by run in
    place. The one drawing scheme of the general engine and of the 3-UPS prediction."""
    if n < 0:
        raise InputError(f'n = {n}: the number of samples must be >= 0')
    out = np.empty((bounds.shape[0], n))
    for first, stop, law, sigmas in runs:
        rows = out[first:stop]
        if law == 'normal':
            rng.standard_normal(out=rows)
            outside = np.abs(rows) > sigmas
            while outside.any():
                rows[outside] = rng.standard_normal(size=int(outside.sum()))
                outside = np.abs(rows) > sigmas
            rows *= (bounds[first:stop] / sigmas)[:, None]
        else:   # uniform on ±t: 2t·U[0, 1) − t
            half = bounds[first:stop, None]
            rng.random(out=rows)
            rows *= 2.0 * half
            rows -= half
    return out


def draw(sources: Sequence[Source], n: int, rng: np.random.Generator) -> FloatArray:
    """n deviations of every source from its law, (S, n) C-ordered (samples contiguous per
    source), SI (m or rad). A source of tolerance 0 gives zeros."""
    return draw_laws(np.array([s.tolerance for s in sources], dtype=float),
                     law_runs(sources), n, rng)
