"""The coordinated cell's calibration (issue 27 item 5): each positioner's base in the cell frame
and its socket's place in the panel, from one tracker's measurements of targets on the panel.

At calibration pose k the cell commands the panel; each positioner i takes its platform goal
and puts its attachment point at a_ik (m, its own base frame: its commanded platform pose
through its own calibrated model, :func:`.base_calibration.attachment_in_base`). The tracker,
located in the cell frame, measures the panel's targets; their fit is the panel's pose
P_k = (R_k, p_k) (cell frame). The panel holds positioner i's ball at b_i (m, panel frame), so

    R_i·a_ik + t_i = R_k·b_i + p_k    (three equations per pose and positioner)

with T_cell_base_i = (R_i, t_i) and b_i unknown: nine per positioner, each positioner's set
apart from the others' once the panel poses are measured. Gauss-Newton from the cell file's
values (the base to within millimetres and a few mrad), the base's turn as a small rotation
about the cell axes (R_i ← exp([δθ]×)·R_i), Jacobian ∂r/∂δθ = −[R_i·a_ik]×, ∂r/∂t = I,
∂r/∂b = −R_k (checked against finite differences, and the solution against scipy's
``least_squares``: ``test/test_cell_calibration.py``).

Only a turned panel separates the socket from the base: with the panel translated alone
(R_k constant) t_i − R_k·b_i is all the data fix. Poses whose turns do not span two axes
are refused (the smallest singular value of the column-scaled Jacobian, :data:`MIN_CONDITION`).

The residuals hold what this model does not: the positioners' own calibration residuals, the
panel's elastic sag and the balls' misfits, the tracker's noise. ``sigma`` (m per axis) is
what the caller expects of them; the variance factor (residual sum of squares over its
degrees of freedom, over sigma²) says how far they exceed it, and a calibration whose factor
passes the χ² bound (:data:`ADEQUACY_QUANTILE`) says its model falls short
(:attr:`SocketFit.adequate`) instead of stating the noise's uncertainty. The covariance is
(JᵀJ)⁻¹·sigma², scaled up by the factor when it exceeds 1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from positioning_cell.coordinated.base_calibration import attachment_in_base
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, matrix_from_quaternion
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import skew

FloatArray = NDArray[np.float64]

#: Fewest panel poses: nine unknowns per positioner, three equations per pose, and turns
#: about two axes.
MIN_POSES = 6
#: The column-scaled Jacobian's smallest singular value over its largest below which the
#: poses are refused (the socket and the base not separated: the panel not turned enough).
MIN_CONDITION = 1e-4
#: The variance factor's χ² quantile above which a fit's model falls short of its residuals.
ADEQUACY_QUANTILE = 0.99
#: Gauss-Newton: most iterations, and the step (m, rad) below which it has converged.
MAX_ITERATIONS, STEP_TOLERANCE = 20, 1e-12
#: The length (m) that scales a rotation column to a length in the condition check.
LEVER = 1.0


class SocketFit(NamedTuple):
    """One positioner of the calibrated cell: its base in the cell frame (``base_position``
    (3,) m, ``base_quaternion`` (4,) x, y, z, w), its socket ``in_panel`` (3,) m (panel
    frame), ``covariance`` (9, 9) of (δθ rad about the cell axes, δt m, δb m),
    ``residuals`` (K, 3) m (cell frame) and ``variance_factor`` (module docstring)."""

    name: str
    base_position: FloatArray
    base_quaternion: FloatArray
    in_panel: FloatArray
    covariance: FloatArray
    residuals: FloatArray
    variance_factor: float
    adequate: bool

    @property
    def rms(self) -> float:
        """RMS of the residuals' length, m."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))


class CellCalibration(NamedTuple):
    """Every positioner's :class:`SocketFit`, in the cell file's order."""

    fits: tuple[SocketFit, ...]

    @property
    def adequate(self) -> bool:
        """Whether every positioner's residuals are explained by ``sigma``."""
        return all(f.adequate for f in self.fits)

    def applied(self, cell: CellFile) -> CellFile:
        """``cell`` with the identified bases and sockets (``in_panel``)."""
        by_name = {f.name: f for f in self.fits}
        entries = []
        for e in cell.positioners:
            f = by_name[e.name]
            (x, y, z), (qx, qy, qz, qw) = f.base_position.tolist(), f.base_quaternion.tolist()
            bx, by, bz = f.in_panel.tolist()
            entries.append(replace(e, base_position=(x, y, z), base_quaternion=(qx, qy, qz, qw),
                                   in_panel=(bx, by, bz)))
        return replace(cell, positioners=tuple(entries))


def residuals(rotation: FloatArray, translation: FloatArray, in_panel: FloatArray,
              a_base: FloatArray, r_panel: FloatArray, p_panel: FloatArray) -> FloatArray:
    """r_k = R·a_k + t − (R_k·b + p_k) (K, 3) m: the base (``rotation`` (3, 3),
    ``translation`` (3,)), the socket ``in_panel`` (3,), the attachment points ``a_base``
    (K, 3) (base frame) and the panel poses ``r_panel`` (K, 3, 3), ``p_panel`` (K, 3)."""
    out: FloatArray = (a_base @ rotation.T + translation
                       - np.einsum('kij,j->ki', r_panel, in_panel) - p_panel)
    return out


def jacobian(rotation: FloatArray, a_base: FloatArray, r_panel: FloatArray) -> FloatArray:
    """∂r/∂(δθ, δt, δb) (K, 3, 9) of :func:`residuals` (module docstring)."""
    k = len(a_base)
    out = np.empty((k, 3, 9))
    out[:, :, :3] = -skew(a_base @ rotation.T)
    out[:, :, 3:6] = np.eye(3)
    out[:, :, 6:] = -r_panel
    return out


def _fit_one(name: str, rotation: FloatArray, translation: FloatArray, in_panel: FloatArray,
             a_base: FloatArray, r_panel: FloatArray, p_panel: FloatArray,
             sigma: float) -> SocketFit:
    k = len(a_base)
    for _ in range(MAX_ITERATIONS):
        r = residuals(rotation, translation, in_panel, a_base, r_panel, p_panel).ravel()
        j = jacobian(rotation, a_base, r_panel).reshape(3 * k, 9)
        step = np.linalg.lstsq(j, -r, rcond=None)[0]
        rotation = Rotation.from_rotvec(step[:3]).as_matrix() @ rotation
        translation = translation + step[3:6]
        in_panel = in_panel + step[6:]
        if np.abs(step).max() < STEP_TOLERANCE:
            break
    j = jacobian(rotation, a_base, r_panel).reshape(3 * k, 9)
    scaled = j * np.r_[[1.0 / LEVER] * 3, [1.0] * 6]
    singular = np.linalg.svd(scaled, compute_uv=False)
    if singular[-1] < MIN_CONDITION * singular[0]:
        raise InputError(f'{name}: the {k} panel poses do not separate its base from its '
                         'socket in the panel (the panel must turn about two axes or more)')
    res = residuals(rotation, translation, in_panel, a_base, r_panel, p_panel)
    dof = 3 * k - 9
    factor = float(np.sum(res**2) / dof / sigma**2)
    covariance = np.asarray(np.linalg.inv(j.T @ j) * sigma**2 * max(factor, 1.0), dtype=float)
    quaternion: FloatArray = np.asarray(Rotation.from_matrix(rotation).as_quat(), dtype=float)
    adequate = bool(factor <= chi2.ppf(ADEQUACY_QUANTILE, dof) / dof)
    return SocketFit(name, translation, quaternion, in_panel, covariance, res, factor, adequate)


def calibrate_cell(cell: CellFile, mech: Mechanism, panel_position: ArrayLike,
                   panel_quaternion: ArrayLike, platforms: Sequence[tuple[ArrayLike, ArrayLike]],
                   sigma: float) -> CellCalibration:
    """Each positioner's base and socket (module docstring) from the measured panel poses
    (K, 3) m, (K, 4) (cell frame) and each positioner's commanded platform poses
    ``platforms`` (one (positions (K, 3) m, quaternions (K, 4)) per positioner, in the cell
    file's order, its base frame), starting from ``cell``'s values (its sockets: its
    :meth:`~CellFile.panel_points` for the positioners' machine ``mech``). ``sigma``: the
    residual expected per axis, m. InputError for bad shapes or values, fewer than
    :data:`MIN_POSES` poses, or poses that do not separate a base from its socket."""
    p_panel, q_panel = as_pose_batch(panel_position, panel_quaternion)
    k = len(p_panel)
    if k < MIN_POSES:
        raise InputError(f'{k} panel poses: a cell calibration needs at least {MIN_POSES}')
    if not (np.isfinite(sigma) and sigma > 0.0):
        raise InputError(f'sigma = {sigma!r}: the expected residual must be a finite value > 0 m')
    if len(platforms) != len(cell.positioners):
        raise InputError(f'{len(platforms)} positioners\' platform poses for '
                         f'{len(cell.positioners)} positioners')
    r_panel = matrix_from_quaternion(q_panel)
    start = cell.panel_points(mech)
    fits = []
    for i, (entry, (position, quaternion)) in enumerate(zip(cell.positioners, platforms,
                                                            strict=True)):
        p, q = as_pose_batch(position, quaternion)
        if len(p) != k:
            raise InputError(f'{entry.name}: {len(p)} platform poses for {k} panel poses')
        a_base = attachment_in_base(p, q, entry.offset)
        rotation = matrix_from_quaternion(np.asarray(entry.base_quaternion)[None])[0]
        fits.append(_fit_one(entry.name, rotation, np.asarray(entry.base_position, dtype=float),
                             start[i].copy(), a_base, r_panel, p_panel, sigma))
    return CellCalibration(tuple(fits))
