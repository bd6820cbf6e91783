"""The panel's pose as each positioner's platform pose, and back (issue 27, item 3).

Frames: ``cell`` (the cell file's), each positioner's ``base`` (T_cell_base_i, the cell file's
``base``) and ``platform``, and the ``panel``: the frame that coincides with ``cell`` when
the panel is at home. The panel is rigid and carries every platform with it: at panel pose
T_cell_panel, positioner i's platform is at

    T_base_platform_i = T_cell_base_iᐨ¹ · T_cell_panel · X_i,

X_i = T_panel_platform_i its platform in the panel frame: turned as T_cell_base_i · T_base_home
turns it, placed so that its attachment point (``offset``) is the panel's (``in_panel``,
:meth:`~positioning_cell.coordinated.cell_file.CellFile.panel_points`); without ``in_panel``,
X_i = T_cell_base_i · T_base_home, every platform at home with the panel. A ball attachment
so turns nothing in its socket (the positioner's idle freedom, a turn about its ball, is held
at zero: :mod:`.mobility`). Back from the platforms, each positioner implies a
panel pose of its own; where they differ the positioners disagree, and what a rigid panel on
balls cannot take is the change of the distance between two balls
(:func:`pair_disagreement`: one internal force system per pair, :mod:`.internal_forces`).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.correction import mean_pose

FloatArray = NDArray[np.float64]


def panel_about(centre: ArrayLike, move: ArrayLike, rotvec: ArrayLike) -> Transform:
    """T_cell_panel of the panel moved from home by ``move`` (3,) m and turned by the rotation
    vector ``rotvec`` (3,) rad, both in the cell frame, about the point ``centre`` (3,) m of
    the cell frame (the panel's at home): the point goes to ``centre + move``."""
    from scipy.spatial.transform import Rotation

    c = np.asarray(centre, dtype=float)
    rotation = Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix()
    return Transform(c + np.asarray(move, dtype=float) - rotation @ c, rotation)


def bases(cell: CellFile) -> list[Transform]:
    """T_cell_base of every positioner of ``cell``, in its order."""
    return [Transform.from_pq(e.base_position, e.base_quaternion) for e in cell.positioners]


def platforms_in_panel(cell: CellFile, mech: Mechanism) -> list[Transform]:
    """X_i = T_panel_platform of every positioner (module docstring): the platform where it
    is with the panel at home."""
    home = Transform.from_pq(mech.home_position, mech.home_quaternion)
    out = []
    for base, entry, point in zip(bases(cell), cell.positioners, cell.panel_points(mech),
                                  strict=True):
        turned = base @ home
        out.append(Transform(point - turned.R @ np.asarray(entry.offset), turned.R))
    return out


def platform_goals(cell: CellFile, mech: Mechanism, panel_position: ArrayLike,
                   panel_quaternion: ArrayLike) -> list[tuple[FloatArray, FloatArray]]:
    """Each positioner's platform pose in its own base (position (3,) m, quaternion (4,)) that
    puts the panel at ``panel_position`` (3,) m, ``panel_quaternion`` (4,) in the cell frame
    (module docstring). InputError for a pose that is not finite or a non-unit quaternion."""
    panel = Transform.from_pq(panel_position, panel_quaternion)  # InputError: bad pose
    return [(base.inverse() @ panel @ home).to_pq()
            for base, home in zip(bases(cell), platforms_in_panel(cell, mech), strict=True)]


def implied_panels(cell: CellFile, mech: Mechanism,
                   platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[Transform]:
    """The panel pose T_cell_panel each positioner's platform pose (position m, quaternion, in
    its base; one per positioner, in the cell's order) implies."""
    if len(platforms) != len(cell.positioners):
        raise InputError(f'{len(platforms)} platform poses for {len(cell.positioners)} '
                         'positioners')
    return [base @ Transform.from_pq(*pose) @ home.inverse()
            for base, home, pose in zip(bases(cell), platforms_in_panel(cell, mech), platforms,
                                        strict=True)]


def mean_panel(panels: Sequence[Transform]) -> Transform:
    """The mean of panel poses (:func:`~positioning_cell.moves.correction.mean_pose`: the mean
    position, the chordal L2 mean rotation)."""
    return Transform.from_pq(*mean_pose([p.p for p in panels], [p.q for p in panels]))


def nearest_panel(cell: CellFile, mech: Mechanism,
                  platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> Transform:
    """T_cell_panel of the rigid panel nearest to the platform poses ``platforms`` (each in
    its base): the mean of the panel poses they imply."""
    return mean_panel(implied_panels(cell, mech, platforms))


def rigid_placement(cell: CellFile, mech: Mechanism,
                    platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[tuple[FloatArray,
                                                                                 FloatArray]]:
    """The platform poses (each in its base) of the rigid panel nearest to ``platforms``
    (:func:`nearest_panel`). What separates the two is the non-rigid part of the positioners'
    disagreement, the part that loads the panel (relax moves it away; the panel simulator
    turns it into forces)."""
    return platform_goals(cell, mech, *nearest_panel(cell, mech, platforms).to_pq())


def attachment_points(cell: CellFile, mech: Mechanism,
                      platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> FloatArray:
    """(N, 3) m, cell frame: where each positioner's platform pose (in its base) puts its
    attachment point (its ``offset`` in the platform frame)."""
    if len(platforms) != len(cell.positioners):
        raise InputError(f'{len(platforms)} platform poses for {len(cell.positioners)} '
                         'positioners')
    return np.array([(base @ Transform.from_pq(*pose)).apply(np.asarray(e.offset))
                     for base, pose, e in zip(bases(cell), platforms, cell.positioners,
                                              strict=True)])


class PairDisagreement(NamedTuple):
    """The disagreement of two positioners ``first``, ``second`` (their names): ``stretch``
    m, how much longer the distance between their attachment points is than on the rigid
    panel (negative: shorter)."""

    first: str
    second: str
    stretch: float


def pair_disagreement(cell: CellFile, mech: Mechanism,
                      platforms: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[PairDisagreement]:
    """For every pair of positioners, how far their platforms (poses in their bases) pull
    their attachment points apart from where the rigid panel holds them: the distance now
    minus the distance at home (m). A rigid panel on balls takes any motion that keeps every
    such distance; what it cannot take shows here."""
    home = cell.panel_points(mech)
    now = attachment_points(cell, mech, platforms)
    out = []
    for i, j in combinations(range(len(cell.positioners)), 2):
        stretch = float(np.linalg.norm(now[i] - now[j]) - np.linalg.norm(home[i] - home[j]))
        out.append(PairDisagreement(cell.positioners[i].name, cell.positioners[j].name,
                                    stretch))
    return out
