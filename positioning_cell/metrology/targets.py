"""The targets (SMRs) fixed to the platform, in the platform frame (m)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.poses import Triple, matrix_from_quaternion
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Default SMR layout, platform frame (m): a 0.30 m × 0.20 m panel fixture on the platform with
#: a 1.5" SMR at each corner 30 mm above the platform plane, and one on a 100 mm tower over the
#: platform origin, so the five are not coplanar.
DEFAULT_TARGETS: tuple[Triple, ...] = (
    (0.15, 0.10, 0.03), (-0.15, 0.10, 0.03), (-0.15, -0.10, 0.03), (0.15, -0.10, 0.03),
    (0.0, 0.0, 0.10),
)

#: Fewest targets a layout must have.
MIN_LAYOUT_TARGETS = 4

#: Two targets closer than this (m) are one target; an SMR is 38.1 mm across.
_MIN_TARGET_SEPARATION = 1e-3

#: Relative spread below which a set of targets counts as collinear (pose undetermined).
_COLLINEAR = 1e-6


@dataclass(frozen=True)
class TargetLayout:
    """Targets (SMRs) fixed to the platform: centres in the platform frame, rows (T, 3), m.
    At least four, distinct, not all on one line (default :data:`DEFAULT_TARGETS`)."""

    platform: tuple[Triple, ...] = setting(
        DEFAULT_TARGETS, 'SMR centres x, y, z per target (>= 4, distinct, not collinear), '
        'platform frame', 'm', dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)
        check_point_set('platform', self.platform, 'on the platform')

    @cached_property
    def array(self) -> FloatArray:
        """The targets (T, 3), m, platform frame (read-only)."""
        arr = np.asarray(self.platform, dtype=float)
        arr.setflags(write=False)
        return arr

    def in_base(self, position: FloatArray, quaternion: FloatArray) -> FloatArray:
        """Target centres (N, T, 3) m in ``base`` for validated platform poses (N, 3), (N, 4)."""
        rot = matrix_from_quaternion(quaternion)
        out: FloatArray = position[:, None, :] + self.array @ np.swapaxes(rot, -1, -2)
        return out


def check_point_set(name: str, points: Any, where: str) -> None:
    """ParameterError on parameter ``name`` unless the points (T, 3) m are at least
    :data:`MIN_LAYOUT_TARGETS`, pairwise distinct and not all on one line (``where``: the
    targets' place, for the message)."""
    arr = np.asarray(points, dtype=float)
    if arr.shape[0] < MIN_LAYOUT_TARGETS:
        raise ParameterError(name, list(arr.ravel()),
                             f'{arr.shape[0]} targets given, the tracker needs at least '
                             f'{MIN_LAYOUT_TARGETS} {where}')
    gaps = np.linalg.norm(arr[:, None] - arr[None], axis=-1) + np.eye(len(arr))
    if gaps.min() < _MIN_TARGET_SEPARATION:
        i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        raise ParameterError(name, list(arr.ravel()),
                             f'targets {i} and {j} are {gaps[i, j]:.3g} m apart: targets '
                             f'must be >= {_MIN_TARGET_SEPARATION} m apart')
    if collinear(arr[None], np.ones((1, len(arr)), dtype=bool))[0]:
        raise ParameterError(name, list(arr.ravel()),
                             'the targets all lie on one line: they cannot fix a rotation')


def collinear(points: FloatArray, mask: BoolArray) -> BoolArray:
    """True per row where the masked points (N, T, 3) span less than a plane."""
    w = mask / mask.sum(axis=1, keepdims=True)
    centred = (points - np.einsum('nt,ntk->nk', w, points)[:, None]) * np.sqrt(w)[..., None]
    s = np.linalg.svd(centred, compute_uv=False)
    result: BoolArray = s[:, 1] <= _COLLINEAR * s[:, 0]
    return result
