"""A grid of poses over a box of the workspace, kept within every limit of the mechanism: the
production poses a calibration program is designed for (``production:`` of a program file,
:mod:`positioning_cell.calibration.program`) and the poses of an accuracy map (``grid:`` of a
run program, :mod:`positioning_cell.analysis.program`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.limits import within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple, scipy_rotation
from positioning_cell.errors import ConfigError
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PoseGrid:
    """A grid of ``points`` per axis over a box (base frame) centred at ``centre`` with
    ``half_widths``, each point at the home orientation and, with ``tilt`` > 0, also tilted by
    ±``tilt`` about base x and about base y."""

    centre: Triple = setting((0.0, 0.0, 0.196), 'centre of the box', 'm')
    half_widths: Triple = setting((0.005, 0.005, 0.005), 'half-widths of the box', 'm')
    points: int = setting(3, 'grid points per axis (1: the centre only)', low=1, high=9)
    tilt: float = setting(0.0, 'also these tilts about base x and y at every point (0: home '
                          'orientation only)', 'rad', low=0.0, high=0.5)

    def __post_init__(self) -> None:
        check_fields(self)
        if min(self.half_widths) < 0.0:
            raise ParameterError('half_widths', self.half_widths, 'must be >= 0')


def grid_poses(mech: Mechanism, grid: PoseGrid, what: str = 'grid'
               ) -> tuple[FloatArray, FloatArray]:
    """The poses (Q, 3) m, (Q, 4) of ``grid`` within every limit of the mechanism, in grid
    order (x slowest, then y, z, then the tilts); ConfigError naming ``what`` when none is."""
    axes = [c + np.linspace(-h, h, grid.points)
            for c, h in zip(grid.centre, grid.half_widths, strict=True)]
    points = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    rotvecs = [np.zeros(3)]
    if grid.tilt > 0.0:
        rotvecs += [sign * grid.tilt * axis for axis in np.eye(3)[:2] for sign in (1, -1)]
    quats = scipy_rotation().from_rotvec(np.asarray(rotvecs)).as_quat()
    p = np.repeat(points, len(quats), axis=0)
    q = np.tile(quats, (points.shape[0], 1))
    ok = within_limits(mech, p, q)
    if not ok.any():
        raise ConfigError(f'{what}: no pose of the grid is within the limits of the mechanism')
    return p[ok], q[ok]


__all__ = ['PoseGrid', 'grid_poses']
