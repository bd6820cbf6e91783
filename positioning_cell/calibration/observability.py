"""How well a calibration program observes the parameters, and what it predicts at the poses
the cell is used at.

**Observability indices** of the stacked identification Jacobian J (m rows, n columns: the
scaled whitened Jacobian of :func:`positioning_cell.calibration.identify.information_rows`,
stacked over the program's poses; n is taken from the array, whatever the parameter vector's
length), from its singular values σ₁ ≥ … ≥ σₙ (Sun & Hollerbach, "Observability index
selection for robot calibration", ICRA 2008, which names them O1..O5):

- O1 = (σ₁ σ₂ … σₙ)^(1/n) / √m (Borm & Menq, "Determination of optimal measurement
  configurations for robot calibration based on observability measure", IJRR 10(1), 1991:
  the geometric mean of the singular values per measurement; a D-optimal index, since
  σ₁…σₙ = √det(JᵀJ));
- O2 = σₙ / σ₁, the inverse condition number (Driels & Pathre 1990);
- O3 = σₙ, the minimum singular value (Nahvi, Hollerbach & Hayward 1994: the worst-observed
  direction of the parameter space; E-optimality);
- O4 = σₙ² / σ₁, the noise amplification index (Nahvi & Hollerbach 1996).

The condition number σ₁ / σₙ is 1/O2 (inf when σₙ = 0). Each index is larger for a better
program except the condition number.

**Design criteria at production poses.** With the program's information matrix
M = I + Σ_k J_kᵀ J_k (in units of each parameter's expected size; I the weak prior of
:mod:`positioning_cell.calibration.program`) the identified parameters' covariance is
M⁻¹ (first order), and the pose the calibrated machine reaches at a commanded pose P has the
covariance S_P M⁻¹ S_Pᵀ, S_P (6, n) the pose's sensitivity to the (scaled) parameters (the
encoder commands move by ∂e/∂x δx, the pose by the velocity Jacobian of that: the same map as
:func:`positioning_cell.calibration.identify.pose_uncertainty`). The rows of S_P are weighted
(1, 1, 1, L, L, L), L the mechanism's characteristic length, so that its variance
v_P = tr(S_P M⁻¹ S_Pᵀ) is one "equivalent position" variance, m² (rotation counted as the
displacement it makes at L). Over the production poses P = 1..Q:

- I-optimality: the average predicted variance (1/Q) Σ_P v_P = tr(M⁻¹ A) / Q,
  A = Σ_P S_Pᵀ S_P (Atkinson, Donev & Tobias, "Optimum experimental designs", 2007, §10.6,
  integrated/V-optimality over a design region);
- G-optimality: the worst predicted variance max_P v_P (ibid. §10.7, taken over the
  production poses instead of the whole design region);
- D-optimality: −log det M (the program's criterion before; the log of O1's n-th power
  up to the prior).

Smaller is better for all three criteria.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.identify import information_rows
from positioning_cell.calibration.program_settings import CRITERIA  # (module docstring)
from positioning_cell.core.kinematics import jacobian
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.mechanics.statics import Payload, Structure

FloatArray = NDArray[np.float64]



class Indices(NamedTuple):
    """Observability indices of a stacked Jacobian (module docstring): ``rows`` m and
    ``columns`` n; the largest and smallest singular values; the condition number σ₁/σₙ;
    O1..O4 of Sun & Hollerbach (O3 = ``sigma_min``). Dimensionless in the Jacobian's
    units (here: whitened residual per expected parameter size)."""

    rows: int
    columns: int
    sigma_max: float
    sigma_min: float
    condition: float
    o1: float
    o2: float
    o3: float
    o4: float


def indices_of_singular_values(singular_values: ArrayLike, rows: int,
                               columns: int | None = None) -> Indices:
    """The :class:`Indices` of a Jacobian of ``rows`` rows and ``columns`` columns (None: as
    many as singular values) with ``singular_values`` (any order; fewer than ``columns``,
    as for a Jacobian of fewer rows than columns: the others are 0). ValueError for no,
    negative or non-finite singular values, or more of them than columns."""
    sv = np.sort(np.asarray(singular_values, dtype=float).ravel())[::-1]
    n = sv.size if columns is None else columns
    if sv.size == 0 or sv.size > n or np.any(sv < 0.0) or not np.all(np.isfinite(sv)):
        raise ValueError(f'singular values: 1 to {n} finite values >= 0 are needed, got '
                         f'{sv.size}')
    sv = np.concatenate([sv, np.zeros(n - sv.size)])
    top, low = float(sv[0]), float(sv[-1])
    with np.errstate(divide='ignore'):
        o1 = float(np.exp(np.mean(np.log(sv))) / np.sqrt(rows)) if low > 0.0 else 0.0
    o2 = low / top if top > 0.0 else 0.0
    return Indices(rows, n, top, low, 1.0 / o2 if o2 > 0.0 else float('inf'), o1, o2, low,
                   low**2 / top if top > 0.0 else 0.0)


def observability(jacobian_rows: ArrayLike) -> Indices:
    """The :class:`Indices` (module docstring) of an identification Jacobian, stacked (m, n)
    or per pose (N, k, n) (then stacked to (N·k, n))."""
    j = np.asarray(jacobian_rows, dtype=float)
    if j.ndim == 3:
        j = j.reshape(-1, j.shape[2])
    if j.ndim != 2 or j.size == 0:
        raise ValueError(f'a Jacobian (m, n) or (N, k, n) is needed, got shape {j.shape}')
    return indices_of_singular_values(np.linalg.svd(j, compute_uv=False), j.shape[0],
                                      j.shape[1])


def pose_weights(mech: Mechanism) -> FloatArray:
    """The weights (6,) of a pose's components x, y, z (1) and rotation (L, m/rad): an
    "equivalent position" (module docstring)."""
    length = mech.characteristic_length
    return np.array([1.0, 1.0, 1.0, length, length, length])


def pose_sensitivity(mech: Mechanism, payload: Payload, structure: Structure,
                     position: ArrayLike, quaternion: ArrayLike,
                     seating_force: float = 1.0) -> FloatArray:
    """S_P (Q, 6, n) of commanded poses (Q, 3) m, (Q, 4): how the pose the calibrated machine
    reaches there (x, y, z m, rotation weighted by :func:`pose_weights` to m) moves per
    expected size of each parameter (the module docstring's S_P). The encoders' sensitivity
    is the unwhitened one of :func:`information_rows` (no pose noise, unit encoder noise),
    mapped to the pose by the velocity Jacobian (as in
    :func:`positioning_cell.calibration.identify.pose_uncertainty`)."""
    p, q = as_pose_batch(position, quaternion)
    joints = information_rows(mech, payload, structure, p, q, np.zeros((6, 6)), np.ones(6),
                              seating_force)
    out: FloatArray = pose_weights(mech)[:, None] * (jacobian(mech, p, q).matrix @ joints)
    return out


def information(rows: FloatArray) -> FloatArray:
    """M = I + Σ_k J_kᵀ J_k (n, n) of per-pose rows (N, k, n) (module docstring)."""
    n = rows.shape[-1]
    out: FloatArray = np.eye(n) + np.einsum('nki,nkj->ij', rows, rows)
    return out


def predicted_variance(info: FloatArray, sensitivity: FloatArray) -> FloatArray:
    """v_P = tr(S_P M⁻¹ S_Pᵀ) (Q,), m², at each production pose of ``sensitivity`` (Q, 6, n)
    for the information matrix ``info`` (n, n) (module docstring)."""
    cov_scaled = np.linalg.inv(info)
    out: FloatArray = np.einsum('qai,ij,qaj->q', sensitivity, cov_scaled, sensitivity)
    return out


def criterion_value(criterion: str, info: FloatArray, sensitivity: FloatArray) -> float:
    """The value (smaller is better) of ``criterion`` (one of :data:`CRITERIA`) for the
    information matrix ``info`` (n, n): −log det M (D), the mean (I) or the largest (G)
    predicted variance at the poses of ``sensitivity`` (Q, 6, n), m²."""
    if criterion == 'D':
        return -float(np.linalg.slogdet(info)[1])
    variance = predicted_variance(info, sensitivity)
    if criterion == 'I':
        return float(np.mean(variance))
    if criterion == 'G':
        return float(np.max(variance))
    raise ValueError(f'criterion {criterion!r}: one of {", ".join(CRITERIA)}')
