"""Static compliance, ISO 9283:1998 §10: how far the platform yields per unit of a load applied
to it, measured by the tracker while the drives hold their position. Pure library.

The load is applied at the platform origin along one direction e of the base frame (+x … −z)
in steps F_0 = 0 < F_1 < … < F_n (N); at each the averaged tracker position p_k (m, base).
The compliance vector c (3,) m/N is the least-squares slope of the positions against the
load, the intercept free (the unloaded position is measured, not assumed)::

    c = Σ_k (F_k − F̄)(p_k − p̄) / S_FF,    S_FF = Σ_k (F_k − F̄)²

The figure is its magnitude |c|: the displacement per unit load whatever way the platform
yields (a lateral load turns a θ drive and the platform moves across as well as along).
Also given: c·e, the yield along the load, and the largest distance of a step's position from
the fitted line (a machine with joint clearance yields along a bent line). The standard asks
for "the displacement per unit load"; taking it as this slope over all the steps, rather than
the displacement at the largest load alone, is our choice: it uses every step and the noise
of one reading matters less.

U (k = 2) of |c|, GUM first order. The readings' covariances C_k (3, 3) m² are their
independent parts (the tracker's registration, shared by all the readings, moves every p_k
alike and leaves the slope); the slope's covariance is Σ_k w_k² C_k with
w_k = (F_k − F̄)/S_FF. The rig's force scale, known to its stated accuracy a (a share, a bound
taken as rectangular), scales c as a whole: u_rel = a/√3. So
u(|c|)² = ĉᵀ (Σ_k w_k² C_k) ĉ + (|c| u_rel)², ĉ = c/|c|: linear where |c| is well above its
noise, as a positioner's compliance is.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The load directions of the standard's test, base frame, by name.
DIRECTIONS = {'+x': (1.0, 0.0, 0.0), '-x': (-1.0, 0.0, 0.0), '+y': (0.0, 1.0, 0.0),
              '-y': (0.0, -1.0, 0.0), '+z': (0.0, 0.0, 1.0), '-z': (0.0, 0.0, -1.0)}
#: Coverage factor of the expanded uncertainty.
K = 2.0


class Compliance(NamedTuple):
    """The static compliance along one load direction (module docstring): ``compliance`` |c|
    m/N and its U (k = 2) ``u_compliance``; ``along`` c·e m/N; ``slope`` c (3,) m/N, base
    frame; ``nonlinearity`` the largest distance of a step's position from the fitted line,
    m; ``largest_load`` F_n N; ``steps`` the loads measured (with the unloaded one)."""

    compliance: float
    u_compliance: float
    along: float
    slope: FloatArray
    nonlinearity: float
    largest_load: float
    steps: int


def static_compliance(direction: ArrayLike, load: ArrayLike, position: ArrayLike,
                      covariance: ArrayLike, force_accuracy: float) -> Compliance:
    """The compliance (module docstring) of the loads ``load`` (K,) N along the unit vector
    ``direction`` (3,), the averaged positions ``position`` (K, 3) m at them and those
    positions' independent covariances ``covariance`` (K, 3, 3) m²; ``force_accuracy`` the
    rig's stated accuracy (share of the load, a bound). InputError for fewer than two
    different loads or input that is not finite."""
    e = np.asarray(direction, dtype=float)
    f = np.asarray(load, dtype=float)
    p = np.asarray(position, dtype=float)
    c = np.asarray(covariance, dtype=float)
    if e.shape != (3,) or abs(float(np.linalg.norm(e)) - 1.0) > 1e-9:
        raise InputError(f'compliance: the direction must be a unit vector, got {e.tolist()}')
    if f.ndim != 1 or p.shape != (f.size, 3) or c.shape != (f.size, 3, 3):
        raise InputError(f'compliance: {f.size} loads need positions ({f.size}, 3) and '
                         f'covariances ({f.size}, 3, 3), got {p.shape} and {c.shape}')
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(p)) and np.all(np.isfinite(c))
            and math.isfinite(force_accuracy) and force_accuracy >= 0.0):
        raise InputError('compliance: loads, positions, covariances and the force accuracy '
                         'must be finite (the accuracy >= 0)')
    centred = f - f.mean()
    s_ff = float(centred @ centred)
    if np.unique(f).size < 2 or s_ff <= 0.0:
        raise InputError('compliance: at least two different loads are needed')
    weights = centred / s_ff
    slope = weights @ p  # Σ w_k p_k: the intercept drops out as Σ w_k = 0
    line = p.mean(axis=0) + np.outer(centred, slope)
    magnitude = float(np.linalg.norm(slope))
    cov_slope = np.einsum('k,kij->ij', weights**2, c)
    unit = slope / magnitude if magnitude > 0.0 else e
    variance = float(unit @ cov_slope @ unit) + (magnitude * force_accuracy / math.sqrt(3.0))**2
    return Compliance(magnitude, K * math.sqrt(variance), float(slope @ e), slope,
                      float(np.max(np.linalg.norm(p - line, axis=1))), float(f.max()), f.size)
