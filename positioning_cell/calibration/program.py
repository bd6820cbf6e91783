"""The calibration's measurement program: poses chosen from candidates over the workspace so
that the identification is well conditioned, and hold-out poses for validation.

Candidates are drawn uniformly in a box around home (position half-widths m, rotation-vector
half-width rad) and kept only within every limit of the mechanism, with a margin. The program
is chosen greedily: each step adds the candidate that most improves the design criterion of
M = λI + Σ_k J_kᵀ J_k, the information matrix of the scaled whitened identification Jacobian
(:func:`positioning_cell.calibration.identify.information_rows`; λ = 1, a weak prior of one
expected size per parameter). The criteria (:mod:`positioning_cell.calibration.observability`):

- ``D``: the largest log det(M); one step is vectorised over every candidate c:
  log det(M + J_cᵀ J_c) − log det(M) = log det(I₆ + U_c), U_c = J_c M⁻¹ J_cᵀ;
- ``I``: the smallest mean predicted pose variance at the production poses
  (:func:`production_poses`), tr(M⁻¹ A)/Q; adding c lowers the variance v_P at production
  pose P by ‖L_c⁻¹ J_c M⁻¹ S_Pᵀ‖²_F (Sherman–Morrison–Woodbury,
  (M + J_cᵀJ_c)⁻¹ = M⁻¹ − M⁻¹J_cᵀ(I₆ + U_c)⁻¹J_c M⁻¹, L_c L_cᵀ = I₆ + U_c), for every
  candidate and production pose at once;
- ``G``: the smallest worst predicted pose variance at the production poses, max_P v_P, from
  the same per-pose reductions.

The production poses are where the cell is used: the ``production:`` block of a program file
(config/program.yaml), a grid over a box (default: the ISO 9283 cube of the run program).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration import observability as obs
from positioning_cell.calibration.identify import information_rows
from positioning_cell.calibration.program_settings import (
    APPROACH_RULES,
    CRITERIA,
    ProgramSettings,
)
from positioning_cell.config import config_path
from positioning_cell.core.limits import within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.pose_grid import PoseGrid, grid_poses
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.moves.trajectory import MotionLimits, plan_profile
from positioning_cell.parameters import parse_block

FloatArray = NDArray[np.float64]


class Program(NamedTuple):
    """Chosen poses: calibration (N, 3) m / (N, 4) and hold-out (H, 3) / (H, 4), base frame;
    ``log_det`` of the information matrix after each pick (N,); the ``criterion`` it was
    chosen by and that criterion's value after each pick (N,) (``values``: −log det, or m²);
    the observability ``indices`` of its stacked Jacobian (the columns poses alone excite:
    not the thermal and reversal ones, which need the run's conditions); the predicted pose σ (m,
    equivalent position: :mod:`~positioning_cell.calibration.observability`) at each
    production pose (Q,)."""

    position: FloatArray
    quaternion: FloatArray
    hold_out_position: FloatArray
    hold_out_quaternion: FloatArray
    log_det: FloatArray
    criterion: str = 'D'
    values: FloatArray | None = None
    indices: obs.Indices | None = None
    production_sigma: FloatArray | None = None


def production_poses(mech: Mechanism, settings: ProgramSettings
                     ) -> tuple[FloatArray, FloatArray]:
    """The production poses (Q, 3) m, (Q, 4) of the ``production:`` block of the program file
    ``settings.production`` (default: the shipped config/program.yaml; a file without the
    block: :class:`~positioning_cell.core.pose_grid.PoseGrid` defaults), kept within every
    limit of the mechanism.
    ConfigError naming the key for a bad block, or when no pose is within limits."""
    path = Path(settings.production) if settings.production else config_path('program.yaml')
    return grid_poses(mech, parse_block(PoseGrid, path, 'production'), 'production')


def candidates(mech: Mechanism, settings: ProgramSettings) -> tuple[FloatArray, FloatArray]:
    """Candidate poses within every limit (M, 3) m, (M, 4), at most ``settings.candidates``."""
    rng = np.random.default_rng(settings.seed)
    n = settings.candidates
    p = mech.home_position + rng.uniform(-1.0, 1.0, (n, 3)) * np.asarray(settings.position_span)
    q = scipy_rotation().from_rotvec(rng.uniform(-1.0, 1.0, (n, 3))
                                     * settings.rotation_span).as_quat()
    ok = within_limits(mech, p, q)
    return p[ok], q[ok]


def choose(mech: Mechanism, payload: Payload, structure: Structure, settings: ProgramSettings,
           pose_covariance: FloatArray, joint_sigma: FloatArray,
           production: tuple[FloatArray, FloatArray] | None = None) -> Program:
    """The measurement program (module docstring): ``settings.poses`` poses chosen by
    ``settings.criterion`` and ``settings.hold_out`` other candidates drawn at random for
    validation. ``pose_covariance`` (6, 6) is the expected covariance of one averaged pose
    measurement, ``joint_sigma`` (6,) of the averaged encoder readings; ``production`` the
    production poses (Q, 3), (Q, 4) (None: :func:`production_poses` of ``settings``)."""
    p, q = candidates(mech, settings)
    need = settings.poses + settings.hold_out
    if p.shape[0] < need:
        raise ValueError(f'only {p.shape[0]} of {settings.candidates} candidates are within '
                         f'limits; {need} needed: draw more candidates or a smaller box')
    rows = information_rows(mech, payload, structure, p, q, pose_covariance, joint_sigma)
    sens = obs.pose_sensitivity(mech, payload, structure,
                                *(production or production_poses(mech, settings)))
    idx, values, log_det = select(rows, sens, settings.poses, settings.criterion)
    free = np.ones(p.shape[0], dtype=bool)
    free[idx] = False
    rng = np.random.default_rng(settings.seed + 1)
    hold = rng.choice(np.flatnonzero(free), settings.hold_out, replace=False)
    order = visiting_order(mech, p[idx], q[idx])
    sigma = np.sqrt(obs.predicted_variance(obs.information(rows[idx]), sens))
    # the indices of what the poses alone excite: the thermal and reversal columns need the
    # conditions the run will record (their columns are 0 here)
    posed = np.any(rows != 0.0, axis=(0, 1))
    return Program(p[idx][order], q[idx][order], p[hold], q[hold], log_det,
                   settings.criterion, values, obs.observability(rows[idx][:, :, posed]), sigma)


def select(rows: FloatArray, sensitivity: FloatArray, count: int, criterion: str,
           exchange_passes: int = 2) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """Choice of ``count`` of the candidates' rows (C, 6, n) by ``criterion`` (module
    docstring; ``sensitivity`` (Q, 6, n) the production poses' S_P): greedy, then up to
    ``exchange_passes`` passes of exchange (Fedorov's: each pose in turn taken out and the
    best candidate put in its place, when that improves the criterion). Returns the picked
    indices (count,) in the order greedy picked them (exchanged ones in their place), the
    criterion's value after each greedy pick (count,; the last: of the final program) and log
    det M likewise (count,)."""
    if criterion not in CRITERIA:
        raise ValueError(f'criterion {criterion!r}: one of {", ".join(CRITERIA)}')
    info = np.eye(rows.shape[2])
    free = np.ones(rows.shape[0], dtype=bool)
    picked: list[int] = []
    values: list[float] = []
    log_det: list[float] = []
    for _ in range(count):
        gain = _gains(criterion, info, rows, sensitivity)
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        picked.append(k)
        free[k] = False
        info = info + rows[k].T @ rows[k]
        values.append(obs.criterion_value(criterion, info, sensitivity))
        log_det.append(float(np.linalg.slogdet(info)[1]))
    for _ in range(exchange_passes):
        swapped = False
        for slot, old in enumerate(picked):
            without = info - rows[old].T @ rows[old]
            gain = _gains(criterion, without, rows, sensitivity)
            gain[~free] = -np.inf
            gain[old] = _gains(criterion, without, rows[old:old + 1], sensitivity)[0]
            k = int(np.argmax(gain))
            if gain[k] > gain[old] + 1e-9 * abs(gain[old]):
                picked[slot], free[old], free[k] = k, True, False
                info = without + rows[k].T @ rows[k]
                swapped = True
        if not swapped:
            break
    values[-1] = obs.criterion_value(criterion, info, sensitivity)
    log_det[-1] = float(np.linalg.slogdet(info)[1])
    return np.asarray(picked, dtype=np.int64), np.asarray(values), np.asarray(log_det)


def _gains(criterion: str, info: FloatArray, rows: FloatArray,
           sensitivity: FloatArray) -> FloatArray:
    """How much adding each candidate (C, 6, n) improves ``criterion`` at ``info`` (C,), larger
    better (module docstring)."""
    k = rows @ np.linalg.inv(info)                          # J_c M⁻¹, (C, 6, n)
    u = np.eye(6) + k @ np.swapaxes(rows, 1, 2)             # I₆ + U_c
    if criterion == 'D':
        out: FloatArray = np.linalg.slogdet(u)[1]
        return out
    q_count = sensitivity.shape[0]
    x = np.linalg.solve(np.linalg.cholesky(u), k @ sensitivity.reshape(-1, rows.shape[2]).T)
    drop = np.einsum('cap,cap->cp', x, x).reshape(-1, q_count, 6).sum(axis=2)  # (C, Q)
    if criterion == 'I':
        out = drop.mean(axis=1)
        return out
    variance = obs.predicted_variance(info, sensitivity)
    out = variance.max() - (variance - drop).max(axis=1)
    return out


def _separation(mech: Mechanism, p: FloatArray, q: FloatArray, p0: FloatArray,
                q0: FloatArray) -> FloatArray:
    """|Δp| + R_B·angle (m) from one pose (3,), (4,) to poses (N, 3), (N, 4)."""
    angle = (scipy_rotation().from_quat(q) * scipy_rotation().from_quat(q0).inv()).magnitude()
    out: FloatArray = np.linalg.norm(p - p0, axis=1) + mech.characteristic_length * angle
    return out


def visiting_order(mech: Mechanism, p: FloatArray, q: FloatArray) -> NDArray[np.int64]:
    """A short tour of poses (N, 3), (N, 4) from home: nearest neighbour first."""
    left = np.ones(p.shape[0], dtype=bool)
    here_p, here_q = mech.home_position, mech.home_quaternion
    order: list[int] = []
    for _ in range(p.shape[0]):
        dist = np.where(left, _separation(mech, p, q, here_p, here_q), np.inf)
        k = int(np.argmin(dist))
        order.append(k)
        left[k] = False
        here_p, here_q = p[k], q[k]
    return np.asarray(order, dtype=np.int64)


def approach_poses(position: FloatArray, approach: float, rule: str = 'below') -> FloatArray:
    """Where each of a program's poses (N, 3) m, in the order visited, is approached from:
    ``approach`` m along base z below it (``rule`` ``below``), or below and above it in turn
    (``alternate``: the first from below)."""
    if rule not in APPROACH_RULES:
        raise ValueError(f'approach_rule {rule!r}: one of {", ".join(APPROACH_RULES)}')
    p = np.asarray(position, dtype=float).reshape(-1, 3)
    side = np.ones(p.shape[0]) if rule == 'below' else 1.0 - 2.0 * (np.arange(p.shape[0]) % 2)
    out: FloatArray = p - side[:, None] * np.array([0.0, 0.0, approach])
    return out


def duration(mech: Mechanism, p: FloatArray, q: FloatArray, limits: MotionLimits,
             dwell: float, approach: float = 0.0, approach_dwell: float = 0.0,
             rule: str = 'below') -> float:
    """Cell time (s) of visiting poses (N, 3), (N, 4) in order from home and back, each move
    planned as the positioner plans it (:func:`positioning_cell.moves.trajectory
    .plan_profile`), with ``dwell`` s at each pose (settling and the averaged measurement),
    each reached through its approach pose (:func:`approach_poses` by ``rule``;
    ``approach_dwell`` s there) if ``approach`` > 0."""
    if approach > 0.0:
        p = np.stack([approach_poses(p, approach, rule), p], axis=1).reshape(-1, 3)
        q = np.repeat(q, 2, axis=0)
        dwell = dwell + approach_dwell
    path_p = np.vstack([mech.home_position, p, mech.home_position])
    path_q = np.vstack([mech.home_quaternion, q, mech.home_quaternion])
    distance = np.linalg.norm(np.diff(path_p, axis=0), axis=1)
    rot = scipy_rotation().from_quat(path_q)
    angle = (rot[1:] * rot[:-1].inv()).magnitude()
    moves = sum(plan_profile(float(d), float(a), limits)[2]
                for d, a in zip(distance, angle, strict=True))
    return float(moves + dwell * (p.shape[0] // (2 if approach > 0.0 else 1)))
