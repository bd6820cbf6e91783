"""The panel as it really is, held by the positioners' real platforms (issue 27, item 4):
simulation truth. The ``panel_simulator`` node computes it from each set's true platform pose
(/<name>/sim/platform/true_pose) and gives each set's leg driver the wrench the panel puts on
its platform, which the driver's load cells then read (its efforts); nothing of the cell reads
it otherwise (the coordinator estimates the internal force from its trackers:
:mod:`positioning_cell.coordinated.force_watch`).

The real attachment points a_i (where the true platforms put them) are compared with the rigid
placement nearest to them (the mean of the panel poses the true platforms imply,
:mod:`positioning_cell.coordinated.panel_motion`): what separates them deforms each
attachment's elastic lines, and seed 002's compatibility with the panel's weight as the load
gives every attachment's wrench on the panel (:func:`~positioning_cell.coordinated.
internal_forces.wrench_map`, an affine map built once) and each pair's internal force. The
platform takes the opposite wrench; it is given about the platform origin in the set's base
frame, as the drives' statics take an external wrench
(:class:`~positioning_cell.mechanics.statics.Payload`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.internal_forces import pair_map, wrench_map
from positioning_cell.coordinated.panel_motion import (
    attachment_points,
    bases,
    nearest_panel,
    platform_goals,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.frames.transforms import Transform

FloatArray = NDArray[np.float64]


#: Newton steps of the panel's pose (:meth:`PanelTruth.state`): from the placement of an
#: uncalibrated cell (millimetres of misfit) they leave it within 0.1 µm of the springs'
#: energy minimum (test_cell_calibration's second path).
PLACEMENT_STEPS = 3


class PanelState(NamedTuple):
    """The panel held by the true platforms: each pair's internal force (``pairs``, N, largest
    first), the largest force at one attachment (``largest``, N), the wrench the panel puts
    on each platform (``on_platforms``, by name: force N, moment N·m about the platform origin,
    in that positioner's base frame), and where the panel is (``panel``, T_cell_panel: the
    rigid placement moved by the compatibility's displacement, its weight's sag among it)."""

    pairs: tuple[tuple[tuple[str, ...], float], ...]
    largest: float
    on_platforms: dict[str, FloatArray]
    panel: Transform


class PanelTruth:
    """The panel of ``cell`` on positioners whose true machines are near ``mech`` (module
    docstring)."""

    def __init__(self, cell: CellFile, mech: Mechanism) -> None:
        self.cell, self.mech = cell, mech
        attachments = cell.attachments(mech)
        self._home_points = np.array([a.point for a in attachments])
        self._wrenches = wrench_map(attachments, cell.panel.stiffness, cell.panel.weight())
        self._pairs = pair_map(attachments, cell.panel.stiffness)
        self._bases = bases(cell)

    def _misfits(self, platforms: Sequence[tuple[ArrayLike, ArrayLike]], panel: Transform
                 ) -> tuple[FloatArray, FloatArray]:
        """Each attachment's displacement (N, 6) (δp m, δθ rad; in the panel frame, as the
        maps' geometry is the panel at home) of the true platforms from where the rigid panel
        at ``panel`` holds them, and the real attachment points (N, 3) m (cell frame)."""
        placed = platform_goals(self.cell, self.mech, *panel.to_pq())
        real = attachment_points(self.cell, self.mech, platforms)
        rigid = attachment_points(self.cell, self.mech, placed)
        rot = scipy_rotation()
        turns = [(rot.from_matrix(base.R) * rot.from_quat(np.asarray(q, dtype=float))
                  * rot.from_quat(q_placed).inv() * rot.from_matrix(base.R).inv()).as_rotvec()
                 for base, (_, q), (_, q_placed) in zip(self._bases, platforms, placed,
                                                       strict=True)]
        return np.hstack([real - rigid, np.array(turns)]) @ np.kron(np.eye(2), panel.R), real

    def state(self, platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> PanelState:
        """The panel held by the true platform poses ``platforms`` (each in its base, in the
        cell's order). Its pose: from the rigid placement nearest to them, the compatibility's
        displacement taken again about each new pose (:data:`PLACEMENT_STEPS`; Newton's
        method: the displacement is linear about the pose it starts from, and the placement
        may start a few mrad off, with millimetres of misfit in an uncalibrated cell), all in
        the panel frame, where the maps' geometry holds exactly."""
        panel = nearest_panel(self.cell, self.mech, platforms)
        rot = scipy_rotation()
        for _ in range(PLACEMENT_STEPS):
            moved = self._wrenches.displacement(self._misfits(platforms, panel)[0])
            panel = panel @ Transform(moved[:3], rot.from_rotvec(moved[3:]).as_matrix())
        displacements, real = self._misfits(platforms, panel)
        wrenches = self._wrenches.wrenches(displacements)
        on_platforms = {}
        for k, (entry, base) in enumerate(zip(self.cell.positioners, self._bases, strict=True)):
            force_panel, moment_panel = wrenches[k, :3], wrenches[k, 3:]  # the panel frame
            force = panel.R @ force_panel
            couple = panel.R @ (moment_panel - np.cross(self._home_points[k], force_panel))
            origin = (base @ Transform.from_pq(*platforms[k])).p
            about_origin = -couple + np.cross(real[k] - origin, -force)
            on_platforms[entry.name] = np.concatenate([base.R.T @ -force,
                                                       base.R.T @ about_origin])
        pairs = self._pairs.sizes(displacements)
        largest = float(np.linalg.norm(wrenches[:, :3] - self._wrenches.by_load[:, :3],
                                       axis=1).max(initial=0.0))
        return PanelState(pairs, largest, on_platforms, panel)
