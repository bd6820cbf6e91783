"""Tolerance verdicts of settled poses: the tolerances, the verdict of one pose error, and of a
settled visit. SI: m and rad; a value equal to its tolerance passes."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from positioning_cell.accuracy.settle import Visit
from positioning_cell.core.poses import pose_error, row_norms
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, setting

#: Default position tolerance of a settled pose, m (0.05 mm).
POSITION_TOLERANCE = 0.05e-3

#: Default orientation tolerance of a settled pose, rad (0.01°).
ORIENTATION_TOLERANCE = math.radians(0.01)


@dataclass(frozen=True)
class Tolerances:
    """Tolerances of a settled pose: ``position`` (m) on |p − p_cmd| and ``orientation``
    (rad) on the rotation angle of R_cmdᵀ·R (the monitor's ``tolerance:`` block, dynamic).
    Defaults 0.05 mm and 0.01°."""

    position: float = setting(POSITION_TOLERANCE, 'settled-pose tolerance on |p - p_cmd|', 'm',
                              low=0.0, low_open=True, high=0.01, dynamic=True)
    orientation: float = setting(ORIENTATION_TOLERANCE, 'settled-pose tolerance on the '
                                 'rotation angle of R_cmd^T R', 'rad', low=0.0, low_open=True,
                                 high=0.1, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


# -- verdicts --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """A settled pose against the tolerances: errors and tolerances in m and rad. A value
    equal to its tolerance passes."""

    position_error: float
    orientation_error: float
    tolerances: Tolerances

    @property
    def position_ok(self) -> bool:
        """|Δp| <= position tolerance."""
        return self.position_error <= self.tolerances.position

    @property
    def orientation_ok(self) -> bool:
        """Rotation angle <= orientation tolerance."""
        return self.orientation_error <= self.tolerances.orientation

    @property
    def ok(self) -> bool:
        """Both within tolerance."""
        return self.position_ok and self.orientation_ok

    def message(self) -> str:
        """For people: µm and degrees."""
        return (f'position error {self.position_error * 1e6:.1f} µm (tolerance '
                f'{self.tolerances.position * 1e6:.1f} µm), orientation error '
                f'{math.degrees(self.orientation_error):.4f}° (tolerance '
                f'{math.degrees(self.tolerances.orientation):.4f}°): '
                f'{"OK" if self.ok else "OUT OF TOLERANCE"}')

    def short(self) -> str:
        """In a few words, as a run prints it: ``|Δp| 3.2 µm, 0.0004°: OK``."""
        return (f'|Δp| {self.position_error * 1e6:.1f} µm, '
                f'{math.degrees(self.orientation_error):.4f}°: '
                f'{"OK" if self.ok else "OUT OF TOLERANCE"}')

def judge(position_error: float, orientation_error: float,
          tolerances: Tolerances | None = None) -> Verdict:
    """Verdict of a pose error: ``position_error`` |Δp| (m), ``orientation_error`` the
    rotation angle (rad), both finite and >= 0."""
    for name, value in (('position_error', position_error),
                        ('orientation_error', orientation_error)):
        if not (math.isfinite(value) and value >= 0.0):
            raise InputError(f'{name} = {value!r}: must be a finite number >= 0')
    return Verdict(float(position_error), float(orientation_error), tolerances or Tolerances())

def judge_visit(visit: Visit, tolerances: Tolerances | None = None) -> Verdict:
    """Verdict of a settled visit: its attained pose against its commanded pose."""
    return judge_visits([visit], tolerances)[0]


def judge_visits(visits: Sequence[Visit], tolerances: Tolerances | None = None
                 ) -> list[Verdict]:
    """Verdicts of settled visits, their errors computed together (row by row the same as
    one at a time)."""
    if not visits:
        return []
    dp, rv = pose_error(np.array([v.position for v in visits]),
                        np.array([v.quaternion for v in visits]),
                        np.array([v.commanded_position for v in visits]),
                        np.array([v.commanded_quaternion for v in visits]))
    return [judge(float(d), float(a), tolerances) for d, a in zip(row_norms(dp).tolist(),
                                                                  row_norms(rv).tolist(),
                                                                  strict=True)]
