"""Predicted accuracy over the workspace: a grid of platform positions at one height and
orientation, the first-order worst case (seed 004 eq. 15) and 3σ of the position and
orientation error at each, and which kind of source dominates where."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.limits import check_poses
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_unit_quaternions
from positioning_cell.errors import InputError
from positioning_cell.prediction.sensitivity import (
    kind_variances,
    linearise,
    root_sum_square,
    split_norms,
    worst_case,
)
from positioning_cell.prediction.sources import ToleranceSpec

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class WorkspaceMaps:
    """Maps on a (ny, nx) grid of x (nx,) and y (ny,) in m at height ``z`` m, orientation
    ``quaternion`` (4,). ``feasible`` is False where a pose violates a limit of the mechanism
    (values NaN, dominant −1 there). Worst cases are the norms of the per-coordinate worst cases
    (over every clearance direction in the ``any`` gap model; an upper bound of the worst |Δp|
    in m and rotation angle in rad, :func:`.extremes.worst_norm` gives the attained one at a
    pose); 3σ from the linear model.
    ``dominant_*`` index ``kinds``: the kind of source adding the most variance."""

    x: FloatArray
    y: FloatArray
    z: float
    quaternion: FloatArray
    feasible: BoolArray
    worst_position: FloatArray
    worst_orientation: FloatArray
    sigma3_position: FloatArray
    sigma3_orientation: FloatArray
    dominant_position: IntArray
    dominant_orientation: IntArray
    kinds: tuple[str, ...]


def workspace_maps(mech: Mechanism, spec: ToleranceSpec, half_width: float, count: int, *,
                   height: float | None = None,
                   quaternion: ArrayLike = (0.0, 0.0, 0.0, 1.0)) -> WorkspaceMaps:
    """Evaluate the predictions on a ``count`` × ``count`` grid x, y ∈ [−half_width, half_width]
    m at ``height`` m (default: home height) with orientation ``quaternion`` (x, y, z, w).

    Feasibility is checked pose by pose with :func:`positioning_cell.core.limits.check_poses`; the
    sensitivity of all feasible poses is one batched :func:`.sensitivity.linearise`.
    """
    if count < 2 or not half_width > 0.0:
        raise InputError(f'workspace_maps: count = {count}, half_width = {half_width!r}: need '
                         'count >= 2 and half_width > 0 m')
    q = as_unit_quaternions(quaternion)[0]
    z = mech.home_height if height is None else float(height)
    axis = np.linspace(-half_width, half_width, count)
    gx, gy = np.meshgrid(axis, axis)
    positions = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)
    feasible = np.array([check_poses(mech, p, q).ok for p in positions])
    shape = gx.shape
    values = np.full((gx.size, 4), np.nan)
    dominant = np.full((gx.size, 2), -1, dtype=np.int64)
    kinds = tuple(dict.fromkeys(spec.kinds))
    if feasible.any():
        lin = linearise(mech, spec, positions[feasible],
                        np.broadcast_to(q, (int(feasible.sum()), 4)))
        values[feasible, 0:2] = split_norms(worst_case(lin.matrix, spec.bounds, spec.balls))
        values[feasible, 2:4] = 3.0 * split_norms(root_sum_square(lin.matrix, spec.stds))
        kinds, variances = kind_variances(lin.matrix, spec)
        dominant[feasible] = np.argmax(variances, axis=-1)
    return WorkspaceMaps(
        x=axis, y=axis.copy(), z=z, quaternion=q, feasible=feasible.reshape(shape),
        worst_position=values[:, 0].reshape(shape), worst_orientation=values[:, 1].reshape(shape),
        sigma3_position=values[:, 2].reshape(shape),
        sigma3_orientation=values[:, 3].reshape(shape),
        dominant_position=dominant[:, 0].reshape(shape),
        dominant_orientation=dominant[:, 1].reshape(shape), kinds=kinds)
