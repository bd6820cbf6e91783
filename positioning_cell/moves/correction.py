"""The closed loop on the laser tracker: averaged measured poses and the covariance of their
mean, their deviation from the desired pose, and the next command that moves the measured pose
onto it (the way digital assembly cells close the loop through a tracker). Poses in the base
frame: m, unit quaternions x, y, z, w."""

from __future__ import annotations

import math
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import (
    as_pose_batch,
    canonical_quaternions,
    matrix_from_quaternion,
    mean_quaternion,
    pose_error,
    quaternion_from_rotation_vector,
    quaternion_inverse,
    quaternion_product,
    rotation_vector,
)
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import averaged_covariance

FloatArray = NDArray[np.float64]


def corrected_command(command_p: ArrayLike, command_q: ArrayLike, desired_p: ArrayLike,
                      desired_q: ArrayLike, measured_p: ArrayLike,
                      measured_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Next pose to command so that the measured pose moves onto the desired one.

    The machine's error is nearly constant over a correction step, so the command moves by the
    measured deviation: p' = p_cmd + (p_des − p_meas); R' = R_des·R_measᵀ·R_cmd (base frame).
    """
    cp, cq = as_pose_batch(command_p, command_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    mp, mq = as_pose_batch(measured_p, measured_q)
    rot = quaternion_product(quaternion_product(dq, quaternion_inverse(mq)), cq)
    return (cp + dp - mp)[0], canonical_quaternions(rot)[0]

def deviation(measured_p: ArrayLike, measured_q: ArrayLike, desired_p: ArrayLike,
              desired_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Measured − desired: Δp (3,) m and the rotation vector of R_desᵀ·R_meas (3,) rad."""
    mp, mq = as_pose_batch(measured_p, measured_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    e_p, e_r = pose_error(mp, mq, dp, dq)
    return e_p[0], e_r[0]

def mean_pose(positions: ArrayLike, quaternions: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Mean of k poses: arithmetic mean position (3,) m, chordal L2 mean rotation (4,)
    (:func:`~positioning_cell.core.poses.mean_quaternion`)."""
    p, q = as_pose_batch(positions, quaternions)
    return p.mean(axis=0), mean_quaternion(q)


def mean_reading(positions: ArrayLike, quaternions: ArrayLike, covariances: ArrayLike,
                 common: ArrayLike | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The mean of k tracker readings of one pose (:func:`mean_pose`: position (3,) m,
    quaternion (4,)) and the covariance (6, 6) of that mean, from the readings' positions
    (k, 3) m, quaternions (k, 4) and stated covariances (k, 6, 6) in ``base``, order x, y, z,
    rot-x, rot-y, rot-z (m², m·rad, rad²; rotations small angles about the base axes,
    R_i = exp([δθ_i]×)·R̄, as :func:`positioning_cell.metrology.fit.pose_covariance` states them).

    A reading's stated covariance is its own noise plus a part common to all readings (the
    tracker's registration) that averaging does not reduce, so inv(Σ C_i⁻¹) — the readings
    taken as independent — understates the mean's. When that common part is known
    (``common`` (6, 6): the published registration's covariance at these poses,
    :meth:`~positioning_cell.metrology.instrument.Registration.covariance_at`), the mean's
    covariance is common + (C̄ − common)/k, C̄ the mean of the C_i: exact for readings as
    stated, positive semi-definite (a positive mix of C̄ and common). Without it, the
    readings' own scatter tells the two apart: per axis i, the independent share
    f_i = clip(s_i² / C̄_ii, 0, 1) of the mean stated variance C̄_ii (C̄ the mean of the C_i),
    s_i² the sample variance of the positions or of the rotation vectors of R_i·R̄ᵀ; the
    rest is common. The mean's variance is then C̄_ii·(1 − f_i + f_i/k), and its covariance
    D·C̄·D with D = diag(√(1 − f_i + f_i/k)): symmetric positive semi-definite as C̄ is, C̄/k
    for readings scattering as stated, C̄ for identical readings (a single reading: C̄). With
    few readings s_i² is itself uncertain (relative σ √(2/(k − 1))), so the split leans to
    stating more than C̄/k for independent readings; readings scattering beyond their stated
    σ are capped at C̄/k (judging such scatter is the caller's).
    """
    p, q = as_pose_batch(positions, quaternions)
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (len(p), 6, 6):
        raise InputError(f'covariances: expected shape ({len(p)}, 6, 6) for the {len(p)} '
                         f'readings, got {cov.shape}')
    if not np.all(np.isfinite(cov)):
        raise InputError('covariances: not finite')
    position, quaternion = mean_pose(p, q)
    mean_cov = cov.mean(axis=0)
    k = len(p)
    if common is not None:
        return position, quaternion, averaged_covariance(mean_cov, common, k)
    if k > 1:  # the rotation vectors of R_i·R̄ᵀ: R̄ turns those of R̄ᵀ·R_i into base axes
        rotvec = pose_error(p, q, position[None], quaternion[None])[1] \
            @ matrix_from_quaternion(quaternion[None])[0].T
        scatter = np.concatenate([p.var(axis=0, ddof=1), rotvec.var(axis=0, ddof=1)])
    else:
        scatter = np.zeros(6)
    stated = np.diag(mean_cov)
    share = np.clip(np.divide(scatter, stated, out=np.ones(6), where=stated > 0.0), 0.0, 1.0)
    d = np.sqrt(1.0 - share + share / k)
    out: FloatArray = d[:, None] * mean_cov * d[None, :]
    return position, quaternion, 0.5 * (out + out.T)


def unread_sigma(covariances: ArrayLike, common: ArrayLike | None, samples: int) -> FloatArray:
    """How far the mean of ``samples`` readings may still move from the mean of the k read so
    far (stated covariances ``covariances`` (k, 6, 6), base frame, order x, y, z, rot-x,
    rot-y, rot-z): the standard deviation (6,) m and rad of mean_samples − mean_k, the
    readings' independent noise σ² times (1/k − 1/samples) (the variance of a mean of iid
    readings, split at k). The independent noise is the stated C̄ less the part every
    reading shares (``common`` (6, 6), the registration's at these poses, which no number of
    readings changes: :func:`mean_reading`); without it all of C̄ is taken as independent,
    which overstates what the remaining readings can change. Zero once k >= samples."""
    cov = np.asarray(covariances, dtype=float)
    k = cov.shape[0] if cov.ndim == 3 else 0
    if cov.ndim != 3 or cov.shape[1:] != (6, 6) or k < 1 or not np.all(np.isfinite(cov)):
        raise InputError(f'covariances: expected finite (k >= 1, 6, 6), got shape {cov.shape}')
    independent = np.diag(cov.mean(axis=0))
    if common is not None:
        independent = independent - np.diag(np.asarray(common, dtype=float))
    share = max(1.0 / k - 1.0 / samples, 0.0)
    return np.sqrt(np.clip(independent, 0.0, None) * share)


class Verdict(Enum):
    """What a measured error says of a tolerance, its uncertainty taken into account."""

    WITHIN = 'within'        # within, even each component enlarged by its margin
    OUTSIDE = 'outside'      # outside, even each component shrunk by its margin
    UNDECIDED = 'undecided'  # the measurement cannot tell yet


def verdict(position_error: ArrayLike, rotation_error: ArrayLike, sigma: ArrayLike,
            position_tolerance: float, orientation_tolerance: float,
            significance: float) -> Verdict:
    """Whether an error Δp (3,) m, rotation vector (3,) rad measured with standard uncertainty
    ``sigma`` (6,) (x, y, z m, rot-x, rot-y, rot-z rad) is within the tolerances (norms of Δp
    and of the rotation vector, m and rad) beyond doubt: WITHIN when the norms stay within
    both even with every component's magnitude enlarged by ``significance``·σ; OUTSIDE when
    one exceeds its tolerance even with every magnitude shrunk by that much (not below 0);
    else UNDECIDED. With σ = 0 it is the plain comparison of the norms."""
    e = np.abs(np.concatenate([np.asarray(position_error, dtype=float).reshape(3),
                               np.asarray(rotation_error, dtype=float).reshape(3)]))
    margin = significance * np.asarray(sigma, dtype=float).reshape(6)
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(margin)) and np.all(margin >= 0.0)):
        raise InputError('verdict: errors and sigma must be finite, sigma >= 0')
    tolerances = (position_tolerance, orientation_tolerance)

    def norms(v: FloatArray) -> tuple[float, float]:
        return float(np.linalg.norm(v[:3])), float(np.linalg.norm(v[3:]))

    high, low = norms(e + margin), norms(np.maximum(e - margin, 0.0))
    if all(n <= t for n, t in zip(high, tolerances, strict=True)):
        return Verdict.WITHIN
    if any(n > t for n, t in zip(low, tolerances, strict=True)):
        return Verdict.OUTSIDE
    return Verdict.UNDECIDED


def correction_offset(command_p: ArrayLike, command_q: ArrayLike, measured_p: ArrayLike,
                      measured_q: ArrayLike) -> FloatArray:
    """What a settled move's correction was: the offset (6,) from the measured pose to the
    command that put the platform there, p_cmd − p_meas (m) and the rotation vector of
    R_cmd·R_measᵀ (rad), base frame (:func:`offset_command` applies it to another goal as
    :func:`corrected_command` does)."""
    cp, cq = as_pose_batch(command_p, command_q)
    mp, mq = as_pose_batch(measured_p, measured_q)
    turn = quaternion_product(cq, quaternion_inverse(mq))
    return np.concatenate([(cp - mp)[0], rotation_vector(turn)[0]])


def offset_command(goal_p: ArrayLike, goal_q: ArrayLike,
                   offset: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The command (3,) m, (4,) for a goal moved by a correction ``offset`` (6,)
    (:func:`correction_offset`): p = p_goal + Δp, R = exp([θ]×)·R_goal (base frame)."""
    gp, gq = as_pose_batch(goal_p, goal_q)
    off = np.asarray(offset, dtype=float).reshape(6)
    rot = quaternion_product(quaternion_from_rotation_vector(off[3:]), gq[0])
    return gp[0] + off[:3], canonical_quaternions(rot)[0]


def predicted_offset(goals_p: ArrayLike, offsets: ArrayLike, goal_p: ArrayLike,
                     scale: float, rcond: float = 0.2) -> FloatArray:
    """The correction offset (6,) (:func:`correction_offset`) expected at ``goal_p`` (3,) m
    from those of K nearby settled moves, ``offsets`` (K, 6) at their goals (K, 3) m: a
    least-squares affine fit offset(p) = a + B·(p − p̄)/scale, the goals' mean p̄ and
    ``scale`` m (the neighbourhood's size). Directions in which the goals spread less than
    ``rcond`` times the fit's strongest direction (as singular values of [1, (p − p̄)/scale])
    get no slope: one goal, or goals close together, carry their mean offset; goals along a
    line, a slope along it only."""
    g = np.asarray(goals_p, dtype=float).reshape(-1, 3)
    off = np.asarray(offsets, dtype=float)
    if off.shape != (len(g), 6) or len(g) == 0:
        raise InputError(f'offsets: expected shape ({len(g)}, 6) for {len(g)} goals (at least '
                         f'one), got {off.shape}')
    if not (math.isfinite(scale) and scale > 0.0):
        raise InputError(f'scale = {scale!r}: must be a finite length > 0 (m)')
    centre = g.mean(axis=0)
    design = np.hstack([np.ones((len(g), 1)), (g - centre) / scale])
    coef = np.linalg.lstsq(design, off, rcond=rcond)[0]
    at = np.concatenate([[1.0], (np.asarray(goal_p, dtype=float).reshape(3) - centre) / scale])
    out: FloatArray = at @ coef
    return out
