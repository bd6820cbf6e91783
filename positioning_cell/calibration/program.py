"""The calibration's measurement program: poses chosen from candidates over the workspace so
that the identification is well conditioned, and hold-out poses for validation.

Candidates are drawn uniformly in a box around home (position half-widths m, rotation-vector
half-width rad) and kept only within every limit of the mechanism, with a margin. The program
is chosen greedily for D-optimality: each step adds the candidate that most increases
log det(M), M = λI + Σ_k J_kᵀ J_k the information matrix of the scaled whitened
identification Jacobian (:func:`positioning_cell.calibration.identify.information_rows`;
λ a weak prior of one expected size per parameter). One step is vectorised over every
candidate: log det(M + J_cᵀ J_c) − log det(M) = log det(I₆ + J_c M⁻¹ J_cᵀ).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.calibration.identify import information_rows
from positioning_cell.core.limits import within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.moves.trajectory import MotionLimits, plan_profile
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ProgramSettings:
    """The ``calibration.program`` block: how many poses, where candidates come from."""

    poses: int = setting(60, 'calibration poses measured', low=8, high=1000)
    hold_out: int = setting(20, 'validation poses, never used in the fit', low=0, high=1000)
    candidates: int = setting(3000, 'candidate poses drawn to choose from', low=10,
                              high=100000)
    position_span: Triple = setting((0.015, 0.015, 0.012), 'half-widths of the candidate box '
                                    'around home', 'm')
    rotation_span: float = setting(0.12, 'largest rotation-vector component of a candidate',
                                   'rad', low=0.0, high=1.0)
    seed: int = setting(0, 'seed of the candidate draw', low=0, high=2**31 - 1)
    approach: float = setting(0.0005, 'each pose is approached from this far below it along '
                              'base z, the same way every time (0: directly)', 'm', low=0.0,
                              high=0.005)

    def __post_init__(self) -> None:
        check_fields(self)


class Program(NamedTuple):
    """Chosen poses: calibration (N, 3) m / (N, 4) and hold-out (H, 3) / (H, 4), base frame;
    ``log_det`` of the information matrix after each pick (N,)."""

    position: FloatArray
    quaternion: FloatArray
    hold_out_position: FloatArray
    hold_out_quaternion: FloatArray
    log_det: FloatArray


def candidates(mech: Mechanism, settings: ProgramSettings) -> tuple[FloatArray, FloatArray]:
    """Candidate poses within every limit (M, 3) m, (M, 4), at most ``settings.candidates``."""
    rng = np.random.default_rng(settings.seed)
    n = settings.candidates
    p = mech.home_position + rng.uniform(-1.0, 1.0, (n, 3)) * np.asarray(settings.position_span)
    q = Rotation.from_rotvec(rng.uniform(-1.0, 1.0, (n, 3))
                             * settings.rotation_span).as_quat()
    ok = within_limits(mech, p, q)
    return p[ok], q[ok]


def choose(mech: Mechanism, payload: Payload, structure: Structure, settings: ProgramSettings,
           pose_covariance: FloatArray, joint_sigma: FloatArray) -> Program:
    """The measurement program (module docstring): ``settings.poses`` D-optimal poses and
    ``settings.hold_out`` other candidates drawn at random for validation. ``pose_covariance``
    (6, 6) is the expected covariance of one averaged pose measurement, ``joint_sigma`` (6,)
    of the averaged encoder readings."""
    p, q = candidates(mech, settings)
    need = settings.poses + settings.hold_out
    if p.shape[0] < need:
        raise ValueError(f'only {p.shape[0]} of {settings.candidates} candidates are within '
                         f'limits; {need} needed: draw more candidates or a smaller box')
    rows = information_rows(mech, payload, structure, p, q, pose_covariance, joint_sigma)
    count = rows.shape[2]
    info = np.eye(count)
    free = np.ones(p.shape[0], dtype=bool)
    picked: list[int] = []
    log_det: list[float] = []
    for _ in range(settings.poses):
        inv = np.linalg.inv(info)
        gain = np.linalg.slogdet(np.eye(6) + rows @ inv @ np.swapaxes(rows, 1, 2))[1]
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        picked.append(k)
        free[k] = False
        info = info + rows[k].T @ rows[k]
        log_det.append(float(np.linalg.slogdet(info)[1]))
    rng = np.random.default_rng(settings.seed + 1)
    hold = rng.choice(np.flatnonzero(free), settings.hold_out, replace=False)
    idx = np.asarray(picked)
    order = visiting_order(mech, p[idx], q[idx])
    return Program(p[idx][order], q[idx][order], p[hold], q[hold], np.asarray(log_det))


def _separation(mech: Mechanism, p: FloatArray, q: FloatArray, p0: FloatArray,
                q0: FloatArray) -> FloatArray:
    """|Δp| + R_B·angle (m) from one pose (3,), (4,) to poses (N, 3), (N, 4)."""
    angle = (Rotation.from_quat(q) * Rotation.from_quat(q0).inv()).magnitude()
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


def approach_pose(position: FloatArray, approach: float) -> FloatArray:
    """Where a pose (…, 3) m is approached from: ``approach`` m below it along base z."""
    out: FloatArray = position - np.array([0.0, 0.0, approach])
    return out


def duration(mech: Mechanism, p: FloatArray, q: FloatArray, limits: MotionLimits,
             dwell: float, approach: float = 0.0, approach_dwell: float = 0.0) -> float:
    """Cell time (s) of visiting poses (N, 3), (N, 4) in order from home and back, each move
    planned as the positioner plans it (:func:`positioning_cell.moves.trajectory
    .plan_profile`), with ``dwell`` s at each pose (settling and the averaged measurement),
    each reached through its :func:`approach_pose` (``approach_dwell`` s there) if
    ``approach`` > 0."""
    if approach > 0.0:
        p = np.stack([approach_pose(p, approach), p], axis=1).reshape(-1, 3)
        q = np.repeat(q, 2, axis=0)
        dwell = dwell + approach_dwell
    path_p = np.vstack([mech.home_position, p, mech.home_position])
    path_q = np.vstack([mech.home_quaternion, q, mech.home_quaternion])
    distance = np.linalg.norm(np.diff(path_p, axis=0), axis=1)
    rot = Rotation.from_quat(path_q)
    angle = (rot[1:] * rot[:-1].inv()).magnitude()
    moves = sum(plan_profile(float(d), float(a), limits)[2]
                for d, a in zip(distance, angle, strict=True))
    return float(moves + dwell * (p.shape[0] // (2 if approach > 0.0 else 1)))
