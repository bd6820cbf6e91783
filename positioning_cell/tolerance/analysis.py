"""The whole tolerance analysis of one mechanism (seed 004 §3.2 steps 1-3): the nominal
solution, the first-order model (A, U, C, D, T), the worst case (eq. 15), the RSS, each
source's contribution, the Monte Carlo with the nonlinear closure and the yield against each
assembly dimension's requirement. A singular U, or loops that do not close near the given
nominal, refuse the analysis: :attr:`Analysis.refusal` says why, and the matrices at the given
nominal are kept for the report.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.tolerance.linear import SingularLoopsError
from positioning_cell.tolerance.loops import (
    Blocks,
    DerivativeCheck,
    Form,
    Linearisation,
    blocks,
    check_derivatives,
    linearise,
)
from positioning_cell.tolerance.model import Mechanism, OpenLoop, Requirement
from positioning_cell.tolerance.montecarlo import MonteCarloResult, monte_carlo
from positioning_cell.tolerance.stackup import (
    Contributions,
    YieldEstimate,
    contributions,
    estimate_yield,
    root_sum_square,
    worst_case,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
#: Quantiles of the sampled deviations reported: the ±3σ coverage of a normal law.
QUANTILES = (0.00135, 0.99865)


@dataclass(frozen=True)
class SampledStats:
    """One assembly dimension's sampled deviations from its nominal, SI, over the solved
    samples: mean, standard deviation, extremes, the :data:`QUANTILES`; the largest
    |nonlinear − linear| on the same samples."""

    mean: float
    std: float
    minimum: float
    maximum: float
    low: float
    high: float
    linear_std: float
    nonlinearity: float


@dataclass(frozen=True)
class DimensionResult:
    """One assembly dimension (open loop): its ``nominal`` (SI), the requirement's limits as
    deviations from the nominal ``band`` (None without a requirement), its row of T, the
    worst case Σ|T_i|·t_i, the RSS √Σ(T_i·t_i)², the linear-model σ, the contributions
    (Pareto), and from the Monte Carlo the statistics and the yields of the nonlinear and the
    linear model (the same samples)."""

    loop: OpenLoop
    nominal: float
    band: tuple[float, float] | None
    sensitivity: FloatArray
    worst_case: float
    rss: float
    linear_std: float
    contributions: Contributions
    sampled: SampledStats | None
    yield_nonlinear: YieldEstimate | None
    yield_linear: YieldEstimate | None


@dataclass(frozen=True)
class MonteCarloSummary:
    """The run: samples, seed, unsolved samples, the Newton steps (mean, max), seconds, and
    the yield of all requirements together (None without requirements)."""

    samples: int
    seed: int
    unsolved: int
    mean_iterations: float
    max_iterations: int
    seconds: float
    joint_yield: YieldEstimate | None


@dataclass(frozen=True)
class Analysis:
    """What :func:`analyse` found. ``guess_residual`` (E,) h at the given nominal (m or rad)
    and ``at_guess`` the A, U, C, D there (always); ``refusal`` the reason when the analysis
    was refused (then no linearisation or results); ``derivatives`` the analytic against
    finite-difference check when asked; ``samples`` the Monte Carlo's per-sample values."""

    mechanism: Mechanism
    form: Form
    guess_residual: FloatArray
    at_guess: Blocks
    refusal: str | None
    linearisation: Linearisation | None
    derivatives: DerivativeCheck | None
    dimensions: tuple[DimensionResult, ...]
    monte_carlo: MonteCarloSummary | None
    confidence: float
    samples: MonteCarloResult | None = None

    @property
    def refused(self) -> bool:
        """True when the analysis was refused (singular U, loops that do not close)."""
        return self.refusal is not None


def band_of(requirement: Requirement | None, nominal: float) -> tuple[float, float] | None:
    """The requirement's limits as deviations from the computed ``nominal`` (SI)."""
    if requirement is None:
        return None
    ref = nominal if requirement.nominal is None else requirement.nominal
    return ref + requirement.lower - nominal, ref + requirement.upper - nominal


def _inside(values: FloatArray, band: tuple[float, float]) -> BoolArray:
    out: BoolArray = (values >= band[0]) & (values <= band[1])
    return out


def _stats(values: FloatArray, linear: FloatArray) -> SampledStats:
    ok = values[np.isfinite(values)]
    if ok.size == 0:
        nan = float('nan')
        return SampledStats(nan, nan, nan, nan, nan, nan, float(linear.std()), nan)
    low, high = np.quantile(ok, QUANTILES)
    diff = np.abs(values - linear)
    return SampledStats(float(ok.mean()), float(ok.std()), float(ok.min()), float(ok.max()),
                        float(low), float(high), float(linear.std()),
                        float(np.nanmax(diff)) if np.isfinite(diff).any() else float('nan'))


def analyse(mech: Mechanism, *, samples: int = 1_000_000, seed: int = 0,
            check: bool = False, confidence: float = 0.95) -> Analysis:
    """Analyse ``mech``: linearise at the nominal solution (a refusal is returned, not
    raised), stack up, and run ``samples`` Monte Carlo samples (0: none) from
    ``numpy.random.default_rng(seed)``; ``check`` compares the analytic derivatives with
    central differences at the nominal solution."""
    if samples < 0:
        raise InputError(f'samples = {samples}: must be >= 0')
    if not 0.0 < confidence < 1.0:
        raise InputError(f'confidence = {confidence!r}: must lie in (0, 1)')
    form = Form.from_mechanism(mech)
    guess = form.point()
    e = form.n_closure
    residual = form.evaluate(guess)[:e]
    at_guess = blocks(form, form.jacobian(guess))
    try:
        lin = linearise(form)
    except (SingularLoopsError, ConvergenceError) as err:
        return Analysis(mech, form, residual, at_guess, str(err), None, None, (), None,
                        confidence)
    deriv = check_derivatives(form, form.point(u=lin.u0)) if check else None
    bounds = np.array([s.tolerance for s in mech.sources])
    stds = np.array([s.std for s in mech.sources])
    wc = worst_case(lin.T, bounds)
    rss = root_sum_square(lin.T, bounds)
    sigma = root_sum_square(lin.T, stds)
    mc: MonteCarloResult | None = None
    summary: MonteCarloSummary | None = None
    seconds = 0.0
    if samples:
        start = time.perf_counter()
        mc = monte_carlo(mech, samples, np.random.default_rng(seed), lin=lin)
        seconds = time.perf_counter() - start
    results = []
    joint_nl: BoolArray | None = None
    for g, loop in enumerate(mech.open_loops):
        band = band_of(loop.requirement, float(lin.gap0[g]))
        sampled = y_nl = y_lin = None
        if mc is not None:
            sampled = _stats(mc.outputs[:, g], mc.linear[:, g])
            if band is not None:
                inside = mc.converged & _inside(mc.outputs[:, g], band)
                y_nl = estimate_yield(inside, confidence)
                y_lin = estimate_yield(_inside(mc.linear[:, g], band), confidence)
                joint_nl = inside if joint_nl is None else joint_nl & inside
        results.append(DimensionResult(
            loop, float(lin.gap0[g]), band, lin.T[g].copy(), float(wc[g]), float(rss[g]),
            float(sigma[g]), contributions(lin.T[g], bounds, stds), sampled, y_nl, y_lin))
    if mc is not None:
        summary = MonteCarloSummary(
            samples, seed, mc.unsolved, float(mc.iterations.mean()), int(mc.iterations.max()),
            seconds, None if joint_nl is None else estimate_yield(joint_nl, confidence))
    return Analysis(mech, form, residual, at_guess, None, lin, deriv, tuple(results), summary,
                    confidence, mc)
