"""The coordinated cell as it is really installed (issue 27 item 5): simulation truth, for
simulating the cell's calibration and judging it; the cell's own calibration never reads it
(:mod:`positioning_cell.coordinated.cell_calibration`).

- Each positioner's base stands off where the cell file puts it (a seeded installation error:
  ``base_position_sigma`` m per axis, ``base_angle_sigma`` rad about each axis), and its ball
  sits off its nominal place in the panel (``socket_sigma`` m per axis).
- The panel and the positioners holding it are not as stiff as the cell file says
  (``stiffness_factor`` of its ``stiffness``): a relax from the load cells, which takes the
  file's stiffness, leaves that error's share of the force each time it steps
  (:meth:`~positioning_cell.coordinated.coordinator.Coordinator.relax_forces`).
- The panel rests where the true platforms put it (:class:`~positioning_cell.sim.panel.
  PanelTruth` of the true cell, :attr:`CellInstallation.true_cell`): the rigid placement
  nearest to them, moved by seed 002's compatibility under its weight (the balls' misfits
  shared by the springs; the sag about 15 µm for the shipped 45 kg panel on three balls of
  1e7 N/m). Neither the sag nor the misfits are in the cell calibration's model.
- One laser tracker, its true pose and systematic errors in the cell frame
  (:class:`~positioning_cell.sim.tracker.SimulatedTracker`), reads the panel's targets; the cell
  frame is the one the tracker realises (its located registration taken as exact: the frame's
  own tie to the floor is outside this simulation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import bases
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.frames.transforms import Transform
from positioning_cell.metrology.instrument import Tracker, TrackerAccuracy
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.moves.correction import mean_pose
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.sim.panel import PanelTruth
from positioning_cell.sim.tracker import SimulatedTracker, TrackerTruth, observe

FloatArray = NDArray[np.float64]

#: The cell tracker's true place: 2.5 m in front of the shipped cell's panel, 1.8 m up,
#: levelled (its standing axis along cell +z).
CELL_TRACKER = TrackerTruth(position=(0.6, -2.5, 1.8), orientation=(0.0, 0.0, 0.0, 1.0))


def panel_targets(cell: CellFile, mech: Mechanism, margin: float = 0.1,
                  height: float = 0.05) -> TargetLayout:
    """Six targets on the panel (panel frame): the corners and mid-sides of the attachment
    points' box in x, y widened by ``margin`` m, ``height`` m above their highest point (the
    mid-sides a further 20 mm up: not all in one plane)."""
    points = cell.panel_points(mech)
    low, high = points[:, :2].min(axis=0) - margin, points[:, :2].max(axis=0) + margin
    z = points[:, 2].max() + height
    mid = (low + high) / 2.0
    rows = [(low[0], low[1], z), (mid[0], low[1], z + 0.02), (high[0], low[1], z),
            (low[0], high[1], z), (mid[0], high[1], z + 0.02), (high[0], high[1], z)]
    return TargetLayout(tuple((float(x), float(y), float(w)) for x, y, w in rows))


@dataclass(frozen=True)
class InstallationSettings:
    """The ``installation:`` block of the panel simulator (read-only): how far the installed
    cell stands off its file (drawn once from ``seed``), and where the cell's tracker really
    stands, with its systematic errors (simulation truth)."""

    seed: int = setting(0, 'seed of the installation errors', low=0, high=2**31 - 1)
    base_position_sigma: float = setting(1e-3, "each base's place off the cell file's, per "
                                         'axis', 'm', low=0.0, high=0.01)
    base_angle_sigma: float = setting(2e-3, "each base's turn off the cell file's, about each "
                                      'axis', 'rad', low=0.0, high=0.05)
    socket_sigma: float = setting(3e-4, "each ball's socket off its nominal place in the "
                                  'panel, per axis', 'm', low=0.0, high=0.01)
    stiffness_factor: float = setting(0.8, "the attachments' true stiffness over the cell "
                                      "file's (a design figure: the built panel, its sockets "
                                      'and the positioners in series are softer)', low=0.1,
                                      high=10.0)
    tracker: TrackerTruth = group(TrackerTruth, "the cell tracker's true pose in the cell "
                                  'frame and its systematic errors', default=lambda: CELL_TRACKER)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class CellInstallation:
    """The installed ``cell`` of positioners of machine ``mech`` (module docstring): its
    installation ``errors``, its panel ``targets`` (default :func:`panel_targets`) read by
    the tracker (of ``accuracy``)."""

    cell: CellFile
    mech: Mechanism
    errors: InstallationSettings = field(default_factory=InstallationSettings)
    accuracy: TrackerAccuracy = field(default_factory=TrackerAccuracy)
    targets: TargetLayout | None = None

    @cached_property
    def tracker(self) -> SimulatedTracker:
        """The cell's tracker as it really is (truth)."""
        return SimulatedTracker(self.errors.tracker, self.accuracy)

    @cached_property
    def located(self) -> Tracker:
        """The tracker as the cell has it located: at its true pose (the cell frame is the one
        it realises, module docstring)."""
        return Tracker(self.tracker.accuracy, self.tracker.truth.position,
                       self.tracker.truth.orientation)

    @cached_property
    def _draws(self) -> tuple[list[Transform], FloatArray]:
        e = self.errors
        rng = np.random.default_rng(e.seed)
        n = len(self.cell.positioners)
        moves = rng.standard_normal((n, 6))
        out = []
        for base, move in zip(bases(self.cell), moves, strict=True):
            turn = scipy_rotation().from_rotvec(move[3:] * e.base_angle_sigma).as_matrix()
            out.append(Transform(base.p + move[:3] * e.base_position_sigma, turn @ base.R))
        sockets = self.cell.panel_points(self.mech) + rng.standard_normal((n, 3)) \
            * e.socket_sigma
        return out, sockets

    @property
    def true_bases(self) -> list[Transform]:
        """Each positioner's true T_cell_base (truth)."""
        return self._draws[0]

    @property
    def true_sockets(self) -> FloatArray:
        """(N, 3) m: each ball's true place in the panel frame (truth)."""
        return self._draws[1]

    @cached_property
    def layout(self) -> TargetLayout:
        """The panel's targets (panel frame, m): as the cell knows them (its design)."""
        return self.targets or panel_targets(self.cell, self.mech)

    @cached_property
    def true_cell(self) -> CellFile:
        """The cell file of the installed cell (truth): its true bases, sockets and
        stiffness."""
        entries = []
        for entry, base, socket in zip(self.cell.positioners, self.true_bases,
                                       self.true_sockets, strict=True):
            (x, y, z), (qx, qy, qz, qw) = base.p.tolist(), base.to_pq()[1].tolist()
            bx, by, bz = socket.tolist()
            entries.append(replace(entry, base_position=(x, y, z),
                                   base_quaternion=(qx, qy, qz, qw), in_panel=(bx, by, bz)))
        k_force, k_couple = (self.errors.stiffness_factor * k for k in self.cell.panel.stiffness)
        return replace(self.cell, positioners=tuple(entries),
                       panel=replace(self.cell.panel, stiffness=(k_force, k_couple)))

    @cached_property
    def panel(self) -> PanelTruth:
        """The panel on the true platforms of the installed cell (truth)."""
        return PanelTruth(self.true_cell, self.mech)

    def true_panel(self, platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> Transform:
        """T_cell_panel where the panel rests on the true platform poses ``platforms`` (each
        (position (3,) m, quaternion (4,)) in its base; module docstring)."""
        return self.panel.state(platforms).panel

    def read_panel(self, panels: Sequence[Transform], rng: np.random.Generator
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One fit of the tracker's readings of the targets of each true panel pose, through
        its located registration (taken as exact, module docstring): positions (K, 3) m,
        quaternions (K, 4), covariances (K, 6, 6) (δp m, δθ rad about the cell axes)."""
        _, fit = observe(self.tracker, self.located, self.layout, np.array([t.p for t in panels]),
                         np.array([t.to_pq()[1] for t in panels]), rng)
        return fit.position, fit.quaternion, fit.covariance

    def measured_panel(self, panels: Sequence[Transform], rng: np.random.Generator,
                       samples: int = 10) -> tuple[FloatArray, FloatArray]:
        """The cell's measurement of each true panel pose: the mean of ``samples`` fits
        (:meth:`read_panel`); positions (K, 3) m, quaternions (K, 4)."""
        position, quaternion, _ = self.read_panel(
            [t for t in panels for _ in range(samples)], rng)
        out_p, out_q = np.empty((len(panels), 3)), np.empty((len(panels), 4))
        for k in range(len(panels)):  # one mean per pose (the rotation mean: scipy's)
            rows = slice(k * samples, (k + 1) * samples)
            out_p[k], out_q[k] = mean_pose(position[rows], quaternion[rows])
        return out_p, out_q
