"""The coordinated cell's calibration as a procedure (issue 27 item 5): the panel moved through
a program of poses by the cell coordinator, each measured by the cell's tracker reading the
panel's targets, then every positioner's base and socket identified
(:func:`positioning_cell.coordinated.cell_calibration.calibrate_cell`).

The positioners' commanded platform poses are what the coordinator sent them: each panel
pose's platform goals through the cell file (:func:`~positioning_cell.coordinated.
panel_motion.platform_goals`), as each positioner puts its ball there through its own
calibrated model. The program turns the panel about every axis (only turns separate a socket
from its base) and moves it, about the attachment points' centroid: a Halton sequence
(scipy.stats.qmc, unscrambled: the same program every run) over ±``reach`` m and ±``turn``
rad per axis, the panel first at home. The panel ends at home.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import qmc

from positioning_cell.coordinated.cell_calibration import (
    MIN_POSES,
    CellCalibration,
    calibrate_cell,
)
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import panel_about, platform_goals
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.correction import mean_pose
from positioning_cell.parameters import check_fields, setting
from positioning_cell.procedures.port import Moved, ProcedureError

FloatArray = NDArray[np.float64]
Say = Callable[[str], None]


class PanelPort(Protocol):
    """The coordinated cell as this procedure sees it."""

    def move_panel(self, position: ArrayLike, quaternion: ArrayLike,
                   speed_scale: float = 0.0) -> Moved:
        """Move the panel (cell frame; m, x, y, z, w) with every positioner, at ``speed_scale``
        of the positioners' speed limits (0: their own default); how it ended."""
        ...

    def panel_readings(self, count: int, since: float | None = None
                       ) -> tuple[FloatArray, FloatArray]:
        """The first ``count`` readings of the panel's pose by the cell's tracker stamped at or
        after ``since`` (s, :meth:`now`'s clock; None: the call) (positions (count, 3) m,
        quaternions (count, 4), cell frame) (ProcedureError when they do not come)."""
        ...

    def now(self) -> float:
        """The time on the clock that stamps the readings, s."""
        ...


@dataclass(frozen=True)
class PanelCalibrationSettings:
    """The program and the identification (module docstring)."""

    poses: int = setting(12, 'panel poses measured', low=MIN_POSES, high=200)
    reach: float = setting(6e-3, "the panel's move from home per axis, at most", 'm',
                           low=0.0, high=0.05)
    turn: float = setting(6e-3, "the panel's turn about each axis, at most", 'rad',
                          low=1e-4, high=0.05)
    readings: int = setting(10, 'tracker readings averaged per pose', low=1, high=1000)
    speed_scale: float = setting(0.25, "the panel's moves, as a share of the positioners' speed "
                                 "limits: the drives' following errors part the attachments "
                                 'in proportion to the speed', low=0.0, low_open=True,
                                 high=1.0)
    sigma: float = setting(6e-6, 'the residual expected per axis: the panel fit at a ball '
                           "and a positioner's own residual", 'm', low=0.0, low_open=True,
                           high=1e-3)

    def __post_init__(self) -> None:
        check_fields(self)


def calibration_poses(cell: CellFile, mech: Mechanism,
                      settings: PanelCalibrationSettings) -> list[Transform]:
    """The program's panel poses (T_cell_panel), home first (module docstring)."""
    centre = cell.test_point(mech)
    # the sequence's first point is its origin (home, here); the rest fill ±1
    unit = 2.0 * qmc.Halton(d=6, scramble=False).random(settings.poses) - 1.0
    unit[0] = 0.0
    return [panel_about(centre, row[:3] * settings.reach, row[3:] * settings.turn)
            for row in unit]


class PanelCalibrationRun(NamedTuple):
    """What the procedure measured and found: the commanded panel poses, the measured ones
    (positions (K, 3) m, quaternions (K, 4)), and the calibration."""

    commanded: list[Transform]
    measured_position: FloatArray
    measured_quaternion: FloatArray
    calibration: CellCalibration


def run(port: PanelPort, cell: CellFile, mech: Mechanism, settings: PanelCalibrationSettings,
        say: Say = lambda line: None) -> PanelCalibrationRun:
    """The procedure (module docstring). ProcedureError naming the pose when a panel move
    does not settle (the panel is then left where the coordinator stopped it); InputError
    when the poses cannot identify the cell."""
    poses = calibration_poses(cell, mech, settings)
    measured_p, measured_q = np.empty((len(poses), 3)), np.empty((len(poses), 4))
    for k, panel in enumerate(poses):
        moved = port.move_panel(*panel.to_pq(), settings.speed_scale)
        if not moved.success:
            raise ProcedureError(f'panel pose {k + 1} of {len(poses)}: {moved.code or "no answer"}'
                                 f': {moved.reason}', moved.code)
        p, q = port.panel_readings(settings.readings)
        measured_p[k], measured_q[k] = mean_pose(p, q)
        off = np.linalg.norm(measured_p[k] - panel.p) * 1e6
        say(f'panel pose {k + 1}/{len(poses)}: measured {off:.0f} um from its goal at the '
            'panel origin')
    moved = port.move_panel(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), settings.speed_scale)
    if not moved.success:
        raise ProcedureError(f'the panel home: {moved.code or "no answer"}: {moved.reason}',
                             moved.code)
    goals = [platform_goals(cell, mech, *panel.to_pq()) for panel in poses]
    platforms = [(np.array([g[i][0] for g in goals]), np.array([g[i][1] for g in goals]))
                 for i in range(len(cell.positioners))]
    found = calibrate_cell(cell, mech, measured_p, measured_q, platforms, settings.sigma)
    return PanelCalibrationRun(poses, measured_p, measured_q, found)


def summary(found: CellCalibration) -> list[str]:
    """One line per positioner: its base's and socket's change from the cell file, the
    residual RMS, the variance factor, and whether its model holds."""
    lines = []
    for fit in found.fits:
        sigma = np.sqrt(np.diag(fit.covariance))
        lines.append(
            f'{fit.name}: base at {np.round(fit.base_position * 1e3, 3).tolist()} mm '
            f'(σ {np.round(sigma[3:6] * 1e6, 1).tolist()} µm), socket at '
            f'{np.round(fit.in_panel * 1e3, 3).tolist()} mm in the panel; residual RMS '
            f'{fit.rms * 1e6:.1f} µm, variance factor {fit.variance_factor:.2f}'
            + ('' if fit.adequate else ': MORE ERROR THAN THE MODEL EXPLAINS'))
    return lines
