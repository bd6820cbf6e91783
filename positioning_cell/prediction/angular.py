"""Angular error statistics (seed 003): the platform-normal angle and stacked stages.

Seed 003 models a part's angular error as a small rotation of its top face F' relative to its
bottom face F, R = R_X(Δα)·R_Y(Δβ) (eq. 1, Δγ = 0); a stack of n parts has the normal
Z_n = R_1·R_2·…·R_n·e_z (eq. 3) and the angle error Δθ between Z_n and Z_0 = e_z; for one part
Δθ ≈ sqrt(Δα² + Δβ²) (eq. 4). With Δα, Δβ ~ N(μ, σ) the single-part angle is Rice(√2·μ, σ), and
direct assembly of n parts Rice(√2·n·μ, √n·σ) (seed 003 §2.1).

Clocking: part j sits on part j − 1 turned about its axis by ψ_j ∈ {2π·i/k}, the k bolt-hole
positions, so the stack is Π_j R_z(ψ_j)·R_j. Strategies (seed 003 §2):

- direct assembly: every part as delivered, ψ_j = 0 (which is what makes the tilts add up to
  Rice(√2·n·μ, √n·σ); random clocking would not);
- stage by stage: at stage m, the ψ_m that minimises the angle of the first m parts (greedy);
- global: the ψ_2..ψ_n that minimise the final angle (ψ_1 turns the whole stack about e_z and
  cannot change the angle). Exhaustive and exact, by meeting in the middle: with L the product of
  the first h stages and B of the rest, cos Δθ = (Lᵀ·e_z)·(B·e_z), so the k^(n−1) candidates
  are the pairs of k^(h−1) left and k^(n−h) right unit vectors, compared by dot product.

Angles in rad throughout. The paper gives its examples without a unit; this module reads them as
mrad (:data:`PAPER_EXAMPLES`), inside the small-rotation regime eq. (1) assumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import NDArray
from scipy import stats
from scipy.spatial.transform import Rotation

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

_EZ = np.array([0.0, 0.0, 1.0])
#: Seed 003 Table 1: (μ, σ) of Δα and Δβ for the two examples, read as mrad, and the paper's
#: setting: k = 6 bolt holes, 8 parts, 10 000 runs.
PAPER_EXAMPLES = {1: (0.0707e-3, 0.7e-3), 2: (1.0e-3, 0.4188e-3)}
PAPER_HOLES = 6
PAPER_PARTS = 8
PAPER_RUNS = 10_000
#: Largest (runs × candidate pairs) held at once by the global search.
_GLOBAL_BLOCK = 1 << 21


class Strategy(Enum):
    """Assembly strategies of seed 003 §2."""

    DIRECT = 'direct'
    STAGE_BY_STAGE = 'stage_by_stage'
    GLOBAL = 'global'


@dataclass(frozen=True)
class DistributionFit:
    """A scipy.stats law fitted by maximum likelihood: ``name`` ('rice' or 'genextreme'),
    ``params`` in scipy's order (shape, loc, scale; rad), and the Kolmogorov–Smirnov statistic and
    p-value of the data against it (the p-value is optimistic: the parameters came from the same
    data)."""

    name: str
    params: tuple[float, ...]
    ks_statistic: float
    ks_pvalue: float
    samples: int

    def frozen(self) -> stats.rv_continuous:
        """The fitted law as a frozen scipy.stats distribution."""
        law: stats.rv_continuous = getattr(stats, self.name)(*self.params)
        return law


@dataclass(frozen=True)
class AngleFits:
    """Rice and generalised-extreme-value fits of one sample of angles (rad)."""

    rice: DistributionFit
    gev: DistributionFit

    @property
    def rice_nu_sigma(self) -> tuple[float, float]:
        """Rice parameters (ν, σ) in rad, as seed 003 writes Rice(ν, σ)."""
        b, _loc, scale = self.rice.params
        return b * scale, scale


def tilts_from_rotvecs(rotvec: FloatArray) -> FloatArray:
    """Tilt errors (Δα, Δβ) (N, 2) in rad of error rotations given as rotation vectors (N, 3):
    the first two intrinsic X-Y-Z angles, so that R = R_X(Δα)·R_Y(Δβ)·R_Z(Δγ) (seed 003 eq. 1)."""
    out: FloatArray = Rotation.from_rotvec(rotvec).as_euler('XYZ')[:, :2]
    return out


def normal_angles(rotations: Rotation) -> FloatArray:
    """Angle (N,) in rad between R·e_z and e_z: the platform-normal (or stack-axis) error."""
    n = np.atleast_2d(rotations.apply(_EZ))
    out: FloatArray = np.arctan2(np.hypot(n[:, 0], n[:, 1]), n[:, 2])
    return out


def fit_angle_distribution(angles: FloatArray, max_samples: int = 20_000) -> AngleFits:
    """Fit Rice (loc fixed at 0) and generalised extreme value laws to angles (N,) in rad, on the
    first ``max_samples`` (the samples are independent; MLE on 10⁶ would take minutes), with a
    Kolmogorov–Smirnov goodness of fit each. Fitting runs on angles divided by their median so
    the optimiser works near 1."""
    data = np.asarray(angles, dtype=float).ravel()
    data = data[np.isfinite(data)][:max_samples]
    if data.size < 10 or np.any(data < 0.0):
        raise InputError(f'fit_angle_distribution: need >= 10 finite angles >= 0 rad, got '
                         f'{data.size} (min {np.min(data, initial=np.inf)!r})')
    unit = float(np.median(data))
    if unit <= 0.0:
        raise InputError('fit_angle_distribution: median angle is 0 rad; nothing to fit')
    scaled = data / unit
    b, _loc, s = stats.rice.fit(scaled, floc=0.0)
    c, loc, scale = stats.genextreme.fit(scaled)
    fits = []
    for name, params in (('rice', (b, 0.0, s * unit)),
                         ('genextreme', (c, loc * unit, scale * unit))):
        ks = stats.kstest(data, getattr(stats, name)(*params).cdf)
        fits.append(DistributionFit(name, tuple(float(v) for v in params), float(ks.statistic),
                                    float(ks.pvalue), int(data.size)))
    return AngleFits(fits[0], fits[1])


def rice_law(nu: float, sigma: float) -> stats.rv_continuous:
    """Seed 003's Rice(ν, σ) as a frozen scipy.stats law (b = ν/σ, scale = σ), rad."""
    law: stats.rv_continuous = stats.rice(nu / sigma, scale=sigma)
    return law


def draw_part_tilts(runs: int, parts: int, mean: float, std: float,
                    rng: np.random.Generator) -> FloatArray:
    """Part tilt errors (runs, parts, 2): Δα and Δβ each N(mean, std), rad (seed 003 §2.1)."""
    if runs < 1 or parts < 1 or not (std > 0.0 and math.isfinite(mean)):
        raise InputError(f'draw_part_tilts: runs = {runs}, parts = {parts}, mean = {mean!r}, '
                         f'std = {std!r}: need runs, parts >= 1, finite mean and std > 0 rad')
    drawn: FloatArray = rng.normal(mean, std, size=(runs, parts, 2))
    return drawn


def _part_matrices(tilts: FloatArray) -> FloatArray:
    """R_X(Δα)·R_Y(Δβ) (runs, parts, 3, 3) from tilts (runs, parts, 2), seed 003 eq. (1)."""
    runs, parts, _ = tilts.shape
    out: FloatArray = Rotation.from_euler('XY', tilts.reshape(-1, 2)).as_matrix().reshape(
        runs, parts, 3, 3)
    return out


def _clockings(k: int) -> FloatArray:
    """R_z(2π·i/k) (k, 3, 3)."""
    out: FloatArray = Rotation.from_euler(
        'z', 2.0 * np.pi * np.arange(k)[:, None] / k).as_matrix()
    return out


def _angle(v: FloatArray) -> FloatArray:
    """Angle of unit-ish vectors (..., 3) from e_z, rad."""
    out: FloatArray = np.arctan2(np.hypot(v[..., 0], v[..., 1]), v[..., 2])
    return out


def assembly_angles(tilts: FloatArray, holes: int, strategy: Strategy) -> FloatArray:
    """Angle error Δθ (runs, parts) in rad of the stack of the first m parts, m = 1..n, each
    assembled by ``strategy`` with ``holes`` = k clocking positions; tilts (runs, n, 2) rad.

    Direct and stage by stage build the stack once (stage m does not depend on later parts);
    the global optimum is searched afresh for every m.
    """
    if tilts.ndim != 3 or tilts.shape[2] != 2:
        raise InputError(f'tilts: expected shape (runs, parts, 2), got {tilts.shape}')
    if holes < 1:
        raise InputError(f'holes = {holes}: need at least 1 clocking position')
    parts = _part_matrices(tilts)
    if strategy is Strategy.GLOBAL:
        return np.stack([_global_angle(parts[:, :m], _clockings(holes))
                         for m in range(1, parts.shape[1] + 1)], axis=1)
    clock = _clockings(holes if strategy is Strategy.STAGE_BY_STAGE else 1)
    runs, n = parts.shape[:2]
    stack = np.broadcast_to(np.eye(3), (runs, 3, 3))
    out = np.empty((runs, n))
    for m in range(n):
        # candidate stacks S·R_z(ψ)·R_m for every ψ: (runs, k, 3, 3)
        candidates = stack[:, None] @ clock[None] @ parts[:, m, None]
        angles = _angle(candidates[..., :, 2])
        best = np.argmin(angles, axis=1)
        stack = candidates[np.arange(runs), best]
        out[:, m] = angles[np.arange(runs), best]
    return out


def _global_angle(parts: FloatArray, clock: FloatArray) -> FloatArray:
    """Smallest final angle (runs,) over all clockings ψ_2..ψ_n of parts (runs, n, 3, 3)."""
    runs, n = parts.shape[:2]
    h = (n + 1) // 2  # parts 1..h on the left, h+1..n on the right
    k = clock.shape[0]
    left_count, right_count = k ** (h - 1), k ** (n - h)
    block = max(1, _GLOBAL_BLOCK // (left_count * right_count))
    out = np.empty(runs)
    for start in range(0, runs, block):
        p = parts[start:start + block]
        r = p.shape[0]
        # left: w = Lᵀ e_z = R_hᵀ R_z(ψ_h)ᵀ … R_1ᵀ e_z  (ψ_1 = 0), shape (r, k^(h-1), 3)
        w = p[:, 0, 2, :][:, None, :]
        for j in range(1, h):
            w = np.einsum('rcj,qji->rqci', w, clock).reshape(r, -1, 3)  # R_z(ψ)ᵀ w
            w = np.einsum('rji,rcj->rci', p[:, j], w)  # R_jᵀ w
        # right: v = B e_z = R_z(ψ_{h+1}) R_{h+1} … R_z(ψ_n) R_n e_z, shape (r, k^(n-h), 3)
        v = np.broadcast_to(_EZ, (r, 1, 3))
        for j in range(n - 1, h - 1, -1):
            v = np.einsum('rij,rcj->rci', p[:, j], v)  # R_j v
            v = np.einsum('qij,rcj->rqci', clock, v).reshape(r, -1, 3)  # R_z(ψ) v
        dots = w @ v.transpose(0, 2, 1)  # (r, left, right) = cos Δθ
        flat = dots.reshape(r, -1).argmax(axis=1)
        a, b = np.divmod(flat, right_count)
        wa, vb = w[np.arange(r), a], v[np.arange(r), b]
        out[start:start + r] = np.arctan2(np.linalg.norm(np.cross(wa, vb), axis=1),
                                          np.sum(wa * vb, axis=1))
    return out
