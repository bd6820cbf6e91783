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
from positioning_cell.coordinated.panel_motion import bases, platforms_in_panel
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.core.vectors import cross
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.correction import mean_pose

FloatArray = NDArray[np.float64]


#: Newton steps of the panel's pose (:meth:`PanelTruth.state`): from the placement of an
#: uncalibrated cell (millimetres of misfit) they leave it within 0.1 µm of the springs'
#: energy minimum (test_cell_calibration's second path).
PLACEMENT_STEPS = 3
#: A Newton step (m, rad) below which the panel's pose has settled: one step suffices for the
#: misfits of a calibrated cell (micrometres); the second and third are for millimetres.
SETTLED = 1e-7


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
        self._home_points = np.array([a.point for a in attachments])  # the panel frame
        self._wrenches = wrench_map(attachments, cell.panel.stiffness, cell.panel.weight())
        self._pairs = pair_map(attachments, cell.panel.stiffness)
        # the geometry as arrays, once: each base (R_b, t_b), each platform in the panel
        # (X_i: R_x, t_x), each attachment's offset on its platform
        base = bases(cell)
        self._r_base = np.array([b.R for b in base])
        self._t_base = np.array([b.p for b in base])
        carried = platforms_in_panel(cell, mech)
        self._r_x = np.array([x.R for x in carried])
        self._t_x = np.array([x.p for x in carried])
        self._offsets = np.array([e.offset for e in cell.positioners], dtype=float)

    def _misfits(self, real: FloatArray, r_real: FloatArray, panel: Transform) -> FloatArray:
        """Each attachment's displacement (N, 6) (δp m, δθ rad; in the panel frame, as the
        maps' geometry is the panel at home) from where the rigid panel at ``panel`` holds it,
        for the real attachment points ``real`` (N, 3) m and platform orientations ``r_real``
        (N, 3, 3) (cell frame)."""
        rigid = self._home_points @ panel.R.T + panel.p
        r_placed = panel.R @ self._r_x
        turns = scipy_rotation().from_matrix(r_real @ np.swapaxes(r_placed, 1, 2)).as_rotvec()
        out: FloatArray = np.hstack([real - rigid, turns]) @ np.kron(np.eye(2), panel.R)
        return out

    def state(self, platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> PanelState:
        """The panel held by the true platform poses ``platforms`` (each in its base, in the
        cell's order). Its pose: from the rigid placement nearest to them (the mean of the
        panel poses they imply), the compatibility's displacement taken again about each new
        pose (:data:`PLACEMENT_STEPS`; Newton's method: the displacement is linear about the
        pose it starts from, and the placement may start a few mrad off, with millimetres of
        misfit in an uncalibrated cell), all in the panel frame, where the maps' geometry
        holds exactly."""
        rot = scipy_rotation()
        p = np.array([np.asarray(pp, dtype=float) for pp, _ in platforms])
        r_p = rot.from_quat(np.array([np.asarray(q, dtype=float) for _, q in platforms])
                            ).as_matrix()
        origins = np.einsum('nij,nj->ni', self._r_base, p) + self._t_base  # cell frame
        r_real = self._r_base @ r_p
        real = origins + np.einsum('nij,nj->ni', r_real, self._offsets)
        # implied panels T_b·T_p·X⁻¹, then their mean
        r_implied = r_real @ np.swapaxes(self._r_x, 1, 2)
        p_implied = origins - np.einsum('nij,nj->ni', r_implied, self._t_x)
        panel = Transform.from_pq(*mean_pose(p_implied, rot.from_matrix(r_implied).as_quat()))
        displacements = self._misfits(real, r_real, panel)
        for _ in range(PLACEMENT_STEPS):
            moved = self._wrenches.displacement(displacements)
            panel = panel @ Transform(moved[:3], rot.from_rotvec(moved[3:]).as_matrix())
            displacements = self._misfits(real, r_real, panel)
            if np.abs(moved).max() < SETTLED:
                break
        wrenches = self._wrenches.wrenches(displacements)
        on_platforms = {}
        for k, entry in enumerate(self.cell.positioners):
            force_panel, moment_panel = wrenches[k, :3], wrenches[k, 3:]  # the panel frame
            force = panel.R @ force_panel
            couple = panel.R @ (moment_panel - cross(self._home_points[k], force_panel))
            about_origin = -couple + cross(real[k] - origins[k], -force)
            on_platforms[entry.name] = np.concatenate([self._r_base[k].T @ -force,
                                                       self._r_base[k].T @ about_origin])
        pairs = self._pairs.sizes(displacements)
        largest = float(np.linalg.norm(wrenches[:, :3] - self._wrenches.by_load[:, :3],
                                       axis=1).max(initial=0.0))
        return PanelState(pairs, largest, on_platforms, panel)
