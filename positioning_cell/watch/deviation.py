"""The 6-D deviation of the measured pose from the commanded one, as a watch window shows it
(SpatialAnalyzer's "6-D deviation against a frame", PC-DMIS "Nominal − Actual").

The watched pose in frame ``base`` is the platform frame's pose in ``base``; in frame ``user``
it is the user position G = T_user⁻¹ · T_machine · T_object (the object frame, its origin the
pivot, in the user CS: :mod:`positioning_cell.frames.systems`). With G_cmd (from
/positioner/target) and G_meas (from /metrology/pose):

- position deviation Δp = p(G_meas) − p(G_cmd), m, along the frame's axes;
- orientation deviation Δθ = rotation vector of R(G_meas) · R(G_cmd)ᵀ, rad, along the frame's
  axes (for small angles the differences of the fixed-axis angles rx, ry, rz).

|Δp| and |Δθ| in frame ``base`` are the accuracy monitor's position and orientation errors
(|p − p_cmd| and the angle of R_cmdᵀ·R); the verdict uses its tolerances and its decision
rule (:func:`positioning_cell.accuracy.verdicts.judge`), with U (k = 2) of |Δp| and |Δθ| from
the reading's covariance as the monitor takes it
(:func:`positioning_cell.accuracy.decisions.norm_expanded_uncertainty`): conforms,
indeterminate or does not conform. An axis is marked out when its own deviation exceeds the
tolerance of its kind (necessary for the pose to be in). SI throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from positioning_cell.accuracy.decisions import norm_expanded_uncertainty
from positioning_cell.accuracy.verdicts import Tolerances, Verdict, judge
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import (
    FloatArray,
    as_pose_batch,
    euler_xyz_from_quaternion,
    matrix_from_quaternion,
    pose_error,
)
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import USER_FRAME, CoordinateSystems
from positioning_cell.frames.transforms import Transform
from positioning_cell.names import BASE_FRAME, WATCH_FRAMES

#: Monte Carlo draws of U near a zero deviation (the monitor's 10⁵ took ~30 ms a norm, two
#: per drawn reading): U to within a few per cent, for a live display; the monitor's verdict
#: of a settled visit is the one of record.
WATCH_DRAWS = 4_000

#: The six axes of a deviation: positions m, then rotations rad.
AXES = ('x', 'y', 'z', 'rx', 'ry', 'rz')

__all__ = ['AXES', 'WATCH_FRAMES', 'Deviation', 'deviation', 'skew', 'watched_pose',
           'watched_poses']


@dataclass(frozen=True)
class Deviation:
    """One measured pose against the commanded one in ``frame`` (module docstring).

    ``commanded``, ``measured`` (6,): x, y, z m and rx, ry, rz rad (R = Rz·Ry·Rx) of the watched
    pose in ``frame``; ``deviation`` (6,): Δp m and Δθ rad along the frame's axes;
    ``uncertainty`` (6,): the measurement's standard uncertainty (k = 1) of the same six, from
    the tracker's covariance; ``position_uncertainty``, ``orientation_uncertainty``: of |Δp|
    and |Δθ| (along Δp, Δθ; the largest axis σ when the deviation is zero)."""

    frame: str
    commanded: FloatArray
    measured: FloatArray
    deviation: FloatArray
    uncertainty: FloatArray
    position_uncertainty: float
    orientation_uncertainty: float
    verdict: Verdict

    @property
    def tolerances(self) -> Tolerances:
        """The tolerances judged against (the accuracy monitor's)."""
        return self.verdict.tolerances

    @property
    def position_error(self) -> float:
        """|Δp|, m."""
        return self.verdict.position_error

    @property
    def orientation_error(self) -> float:
        """|Δθ|, rad."""
        return self.verdict.orientation_error

    @property
    def axis_tolerance(self) -> FloatArray:
        """(6,) the tolerance each axis is marked against: position (m) for x, y, z,
        orientation (rad) for rx, ry, rz."""
        t = self.tolerances
        return np.array([t.position] * 3 + [t.orientation] * 3)

    @property
    def axis_ok(self) -> np.ndarray:
        """(6,) bool: |deviation| within the axis tolerance (equal passes)."""
        return np.asarray(np.abs(self.deviation) <= self.axis_tolerance)

    @property
    def ok(self) -> bool:
        """The pose in tolerance: |Δp| and |Δθ| within the monitor's tolerances."""
        return self.verdict.ok


def skew(v: FloatArray) -> FloatArray:
    """The cross-product matrix [v]× (3, 3) of ``v`` (3,): [v]× w = v × w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def watched_poses(position: FloatArray, quaternion: FloatArray, frame: str,
                  systems: CoordinateSystems, mech: Mechanism) -> tuple[FloatArray, FloatArray]:
    """The watched poses (positions (N, 3) m, unit quaternions (N, 4) x, y, z, w) of platform
    poses in ``base`` (``position`` (N, 3) m, ``quaternion`` (N, 4)) in ``frame``: the
    platform poses themselves (``base``) or the user positions G (``user``). InputError names
    the frames for any other."""
    if frame == BASE_FRAME:
        return as_pose_batch(position, quaternion)
    if frame == USER_FRAME:
        return systems.user_positions(position, quaternion, mech)
    raise InputError(f'watch frame {frame!r}: expected one of {", ".join(WATCH_FRAMES)}')


def watched_pose(position: FloatArray, quaternion: FloatArray, frame: str,
                 systems: CoordinateSystems, mech: Mechanism) -> Transform:
    """:func:`watched_poses` of one platform pose ((3,) m, (4,)), as a Transform."""
    p, q = watched_poses(position, quaternion, frame, systems, mech)
    return Transform.from_pq(p[0], q[0])


def _frame_jacobian(frame: str, r_object: FloatArray,
                    systems: CoordinateSystems) -> FloatArray:
    """(6, 6) first-order map from a perturbation of the measured platform pose in ``base``
    (δp m, δθ rad, ROS PoseWithCovariance order: rotation about the fixed x, y, z) to the
    perturbation of the watched pose along ``frame``'s axes: the watched point is the platform
    origin (``base``) or the object origin p + r (``user``; ``r_object`` = R·t_object (3,),
    base axes): δp_point = δp − [r]×·δθ."""
    if frame == BASE_FRAME:
        return np.eye(6)
    point = np.block([[np.eye(3), -skew(r_object)], [np.zeros((3, 3)), np.eye(3)]])
    axes = systems.user.R.T  # the machine CS's axes are base's
    jac: FloatArray = np.block([[axes, np.zeros((3, 3))], [np.zeros((3, 3)), axes]]) @ point
    return jac


def _along(d: FloatArray, cov: FloatArray) -> float:
    """Standard uncertainty of |d| (first order: along d), or of the largest axis at d = 0."""
    n = float(np.linalg.norm(d))
    if n == 0.0:
        return float(np.sqrt(np.max(np.diag(cov))))
    u = d / n
    return float(np.sqrt(max(float(u @ cov @ u), 0.0)))


def deviation(commanded: tuple[FloatArray, FloatArray], measured: tuple[FloatArray, FloatArray],
              covariance: FloatArray, frame: str, systems: CoordinateSystems,
              mech: Mechanism, tolerances: Tolerances) -> Deviation:
    """The :class:`Deviation` of the ``measured`` platform pose from the ``commanded`` one
    (each (position (3,) m, unit quaternion (4,) x, y, z, w) in ``base``; ``covariance`` (6, 6)
    the measurement's, ROS order x, y, z, rot x, rot y, rot z, m² and rad², base axes) in
    ``frame`` (``base`` or ``user``) against ``tolerances``. Both poses go through each step
    as one batch (a watch computes this per measurement)."""
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (6, 6) or not np.isfinite(cov).all():
        raise InputError(f'covariance: expected a finite (6, 6), got shape {cov.shape}')
    p_base = np.stack([np.asarray(commanded[0], float), np.asarray(measured[0], float)])
    q_base = np.stack([np.asarray(commanded[1], float), np.asarray(measured[1], float)])
    p, q = watched_poses(p_base, q_base, frame, systems, mech)
    dp = p[1] - p[0]
    # The rotation vector of R_m·R_cᵀ (base axes) is R_c times that of R_cᵀ·R_m (pose_error's):
    # numpy, not scipy.spatial, whose import held ``cell watch``'s first table ~0.3 s back.
    r_commanded = matrix_from_quaternion(q[:1])[0]
    dtheta = r_commanded @ pose_error(p[1:], q[1:], p[:1], q[:1])[1][0]
    r_object = (matrix_from_quaternion(q_base[1:])[0] @ systems.object.p if frame == USER_FRAME
                else np.zeros(3))
    jac = _frame_jacobian(frame, r_object, systems)
    cov_frame = jac @ cov @ jac.T
    sigma = np.sqrt(np.clip(np.diag(cov_frame), 0.0, None))
    # the decision by the monitor's rule, U (k = 2) of |Δp| and |Δθ| as the monitor takes it
    verdict = judge(float(np.linalg.norm(dp)), float(np.linalg.norm(dtheta)), tolerances,
                    *(float(norm_expanded_uncertainty(d[None], c[None], draws=WATCH_DRAWS)[0])
                      for d, c in ((dp, cov_frame[:3, :3]), (dtheta, cov_frame[3:, 3:]))))
    six = np.concatenate([p, euler_xyz_from_quaternion(q)], axis=1)
    return Deviation(frame=frame, commanded=six[0], measured=six[1],
                     deviation=np.concatenate([dp, dtheta]), uncertainty=sigma,
                     position_uncertainty=_along(dp, cov_frame[:3, :3]),
                     orientation_uncertainty=_along(dtheta, cov_frame[3:, 3:]),
                     verdict=verdict)
