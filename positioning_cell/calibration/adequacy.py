"""Is the identified model adequate? What physics the model holds it is fitted to; what it
cannot hold, a χ² test of its residuals finds.

Test: the residuals r_k (6,) of N poses, whitened by their covariance C_k (the tracker's through
the inverse Jacobian and the encoders') plus a declared model allowance A = diag(a_l², a_θ²)
(what the model is allowed to miss: a per leg, a_θ per θ axis), sum to χ² with 6N − n degrees
of freedom for the fit (n identified parameters), 6N for hold-out poses (whose covariance also
carries the parameters' own uncertainty). The model is adequate when the p-value
P(χ² ≥ statistic) is at least the threshold.

When it is not, the stated uncertainty is widened: a model error s per joint kind (legs m, θ
rad) such that each kind's residuals, over their diagonal variance C_jj + a² + s², average 1
(χ²/dof = 1), carried into the pose uncertainty as an independent joint error
(:func:`positioning_cell.calibration.identify.pose_uncertainty`); and the residual pattern
names the likely missing effect: the share of the normalised residuals a per-axis regression on
each effect's signature explains (leg and θ efforts: compliance; temperature: thermal; approach
sign: reversal; sin and cos of 2π l / pitch: the screw's periodic error; leg length: lead), the
most significant by an F test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: The effects a residual pattern can point to, and the class that would model it.
EFFECTS = {'compliance': 'joint effort', 'thermal': 'temperature', 'reversal': 'approach sign',
           'screw periodic': 'sin/cos(2 pi l / pitch)', 'lead': 'leg length'}


class Suspect(NamedTuple):
    """One effect the residuals correlate with: its name (:data:`EFFECTS`), the share of the
    residual sum of squares it explains (0..1) and the F test's p-value."""

    effect: str
    explained: float
    p_value: float


@dataclass(frozen=True)
class Adequacy:
    """A χ² test of residuals (module docstring): ``label`` (fit, hold-out), the statistic,
    its degrees of freedom, its p-value, the ``threshold``, the ``model_error`` (6,) m, rad
    that makes χ²/dof = 1 (0 when adequate) and the ``suspects``, most significant first
    (empty when adequate)."""

    label: str
    statistic: float
    dof: int
    p_value: float
    threshold: float
    model_error: FloatArray
    suspects: tuple[Suspect, ...] = ()

    @property
    def adequate(self) -> bool:
        """The p-value is at least the threshold."""
        return self.p_value >= self.threshold

    def verdict(self) -> str:
        """One line: the verdict with its figures (and what is likely missing)."""
        head = (f'{self.label}: chi2 {self.statistic:.1f} for {self.dof} degrees of freedom, '
                f'p = {self.p_value:.3g}')
        if self.adequate:
            return f'{head}: model adequate (p >= {self.threshold:g})'
        line = (f'{head}: model inadequate (p < {self.threshold:g}); uncertainty widened by '
                f'{self.model_error[0] * 1e6:.2f} um per leg, {self.model_error[3] * 1e6:.1f} '
                'urad per theta')
        if self.suspects:
            top = self.suspects[0]
            line += (f'; likely missing: {top.effect} (residuals follow the '
                     f'{EFFECTS[top.effect]}: {top.explained:.0%} explained, p = '
                     f'{top.p_value:.2g})')
        return line

    def to_document(self) -> dict[str, object]:
        """The file's entry (:mod:`positioning_cell.calibration.file`)."""
        return {'label': self.label, 'chi2': round(self.statistic, 3), 'dof': self.dof,
                'p_value': float(self.p_value), 'threshold': self.threshold,
                'adequate': self.adequate,
                'model_error': {'length_m': float(self.model_error[0]),
                                'theta_rad': float(self.model_error[3])},
                'likely_missing': [s.effect for s in self.suspects]}


def allowance_covariance(allowance_length: float, allowance_theta: float) -> FloatArray:
    """The declared model allowance as a joint covariance (6, 6), m², rad²."""
    return np.diag([allowance_length**2] * 3 + [allowance_theta**2] * 3)


def chi2_statistic(residuals: FloatArray, covariance: FloatArray) -> float:
    """Σ r_kᵀ C_k⁻¹ r_k of residuals (N, 6) with covariances (N, 6, 6)."""
    if residuals.shape[0] == 0:
        return 0.0
    chol = np.linalg.cholesky(covariance)
    white = np.linalg.solve(chol, residuals[..., None])[..., 0]
    return float(np.sum(white**2))


def model_error(residuals: FloatArray, covariance: FloatArray, dof: int) -> FloatArray:
    """Per joint kind (legs, θ), the error s (6,) m, rad that brings the residuals (N, 6) over
    their variances diag(C_k) + s² to a mean of 1 per degree of freedom (each kind its share
    of ``dof``; 0 where they are already within)."""
    n = residuals.shape[0]
    out = np.zeros(6)
    if n == 0 or dof <= 0:
        return out
    var = np.diagonal(covariance, axis1=1, axis2=2)
    for cols in (slice(0, 3), slice(3, 6)):
        r2, v = residuals[:, cols]**2, var[:, cols]
        target = dof * r2.size / residuals.size

        def excess(s2: float, r2: FloatArray = r2, v: FloatArray = v,
                   target: float = target) -> float:
            return float(np.sum(r2 / (v + s2)) - target)

        if excess(0.0) <= 0.0:
            continue
        high = float(np.mean(r2)) * 10.0 + float(v.max())
        import scipy.optimize  # here: the positioner loads this module, only calibrations fit

        out[cols] = np.sqrt(scipy.optimize.brentq(excess, 0.0, high, xtol=1e-30, rtol=1e-10))
    return out


def signatures(efforts: FloatArray | None, temperature: FloatArray | None,
               approach: FloatArray | None, lengths: FloatArray,
               pitch: float) -> dict[str, FloatArray]:
    """Each effect's signature per joint (N, 6, k) (:data:`EFFECTS`; a joint where it does not
    act: zeros), from the poses' efforts (N, 6), temperatures (N,), approach signs (N, 6) and
    leg lengths (N, 3) m; ``pitch`` m of the screws."""
    n = lengths.shape[0]
    out: dict[str, FloatArray] = {}
    if efforts is not None:
        out['compliance'] = efforts[..., None]
    if temperature is not None:
        out['thermal'] = np.broadcast_to(temperature[:, None, None], (n, 6, 1)).copy()
    if approach is not None:
        out['reversal'] = approach[..., None]
    angle = 2.0 * np.pi * lengths / pitch
    periodic = np.zeros((n, 6, 2))
    periodic[:, :3, 0], periodic[:, :3, 1] = np.sin(angle), np.cos(angle)
    out['screw periodic'] = periodic
    lead = np.zeros((n, 6, 1))
    lead[:, :3, 0] = lengths
    out['lead'] = lead
    return out


def suspects(residuals: FloatArray, covariance: FloatArray,
             signature: dict[str, FloatArray], threshold: float) -> tuple[Suspect, ...]:
    """The effects whose signature explains the residuals (N, 6) (normalised by the square
    root of their variances diag(C_k)) beyond chance at p < ``threshold`` by an F test of a
    per-joint regression on [1, signature], the most significant first."""
    import scipy.special  # here: ~0.14 s of the positioner's start, which tests nothing

    n = residuals.shape[0]
    z = residuals / np.sqrt(np.diagonal(covariance, axis1=1, axis2=2))
    found = []
    for effect, sig in signature.items():
        explained = total = 0.0
        params = 0
        for j in range(6):
            f = sig[:, j, :]
            keep = np.ptp(f, axis=0) > 0.0
            if not keep.any():
                continue
            design = np.column_stack([np.ones(n), f[:, keep]])
            coef, *_ = np.linalg.lstsq(design, z[:, j], rcond=None)
            centred = z[:, j] - z[:, j].mean()
            fitted = design @ coef - z[:, j].mean()
            explained += float(fitted @ fitted)
            total += float(centred @ centred)
            params += int(keep.sum())
        df2 = 6 * n - 6 - params
        if params == 0 or df2 <= 0 or total <= 0.0:
            continue
        rest = max(total - explained, 1e-300)
        # F distribution survival function (scipy.stats.f.sf; scipy.stats itself costs a
        # node ~23 MB and 0.7 s to import)
        p = float(scipy.special.fdtrc(params, df2, (explained / params) / (rest / df2)))
        if p < threshold:
            found.append(Suspect(effect, explained / total, p))
    return tuple(sorted(found, key=lambda s: s.p_value))


def assess(label: str, residuals: FloatArray, covariance: FloatArray, dof: int,
         threshold: float, signature: dict[str, FloatArray] | None = None) -> Adequacy:
    """The χ² test (module docstring) of residuals (N, 6) with covariances (N, 6, 6) (the
    measurement's and the allowance) for ``dof`` degrees of freedom; when it fails, the model
    error and the suspects among ``signature`` (:func:`signatures`)."""
    import scipy.special  # here, as in suspects

    stat = chi2_statistic(residuals, covariance)
    p = float(scipy.special.chdtrc(dof, stat)) if dof > 0 else 1.0  # χ² survival function
    if p >= threshold:
        return Adequacy(label, stat, dof, p, threshold, np.zeros(6))
    error = model_error(residuals, covariance, dof)
    found = suspects(residuals, covariance, signature or {}, threshold)
    return Adequacy(label, stat, dof, p, threshold, error, found)
