"""The forces in a panel held by several positioners that do not quite agree (issue 27 item 4;
seed 002 §3, deformation compatibility).

Each attachment holds the panel through elastic lines: its :attr:`~.attachments.Attachment.
wrench_lines` (unit forces through the attachment point, a clamp's unit couples), each with
the stiffness of the positioner there in series with the panel's own there: ``k_force`` (N/m)
on each force line, ``k_couple`` (N·m/rad) on each couple. Positioner i puts its attachment
off where it should be by a small displacement (δp_i m at the attachment point, δθ_i rad):
its real pose off the commanded one (geometric errors, clearance, a calibration wrong by
0.2 mm). Along a line j of attachment i that is the line's deformation at zero force,
d0_j = s_j·δp_i (a force line along s_j) or a_j·δθ_i (a couple about a_j); the panel's own
small displacement δx (δp of the cell origin, δθ) takes W_j·δx of it; the line carries
f_j = k_j (d0_j − W_j·δx) on the panel. Equilibrium with the load w (the panel's weight at
its centre of gravity) closes it: :func:`positioning_cell.mechanics.overconstrained.
solve_compatible` (seed 002 eqs. 24, 28).

The **internal** part of the forces is what remains once the load's own share (the same cell
with no displacement) is taken away: it is in self-equilibrium, a combination of the cell's
internal force systems (:mod:`.mobility`), and is decomposed on their pairwise basis, so that
each pair of attachments gets the size of the force system it carries (N, its largest
force) and the worst pair is named: the two positioners that disagree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.attachments import Attachment
from positioning_cell.coordinated.mobility import cell_mobility
from positioning_cell.errors import InputError
from positioning_cell.mechanics.overconstrained import solve_compatible

FloatArray = NDArray[np.float64]


class PanelForces(NamedTuple):
    """The solution: ``wrenches`` (N, 6) each attachment's wrench on the panel (f N; m N·m about
    the cell origin), ``displacement`` (6,) the panel's (δp m of the cell origin, δθ rad),
    ``internal`` (N, 6) their self-equilibrated part, ``pairs`` the size (N) of the internal
    force systems each pair (or group) of attachments carries, largest first."""

    names: tuple[str, ...]
    wrenches: FloatArray
    displacement: FloatArray
    internal: FloatArray
    pairs: tuple[tuple[tuple[str, ...], float], ...]

    @property
    def worst_pair(self) -> tuple[str, ...] | None:
        """The attachments whose internal force system is largest (None: no internal force
        system in this cell)."""
        return self.pairs[0][0] if self.pairs else None

    @property
    def largest_internal_force(self) -> float:
        """The largest internal force at any attachment, N."""
        return float(np.linalg.norm(self.internal[:, :3], axis=1).max(initial=0.0))


def _per_attachment(values: ArrayLike, n: int, width: int, name: str, unit: str) -> FloatArray:
    a = np.asarray(values, dtype=float)
    if a.shape == (width,):
        a = np.broadcast_to(a, (n, width))
    if a.shape != (n, width) or not np.isfinite(a).all():
        raise InputError(f'{name}: expected {n} rows of {width} finite numbers ({unit}), got '
                         f'shape {a.shape}')
    return a


def _solve(lines: FloatArray, stiffness: FloatArray, load: FloatArray, d0: FloatArray,
           owner: list[int], n: int) -> tuple[FloatArray, FloatArray]:
    solution = solve_compatible(lines, stiffness, load, d0)
    per = np.zeros((n, 6))
    np.add.at(per, owner, solution.forces[:, None] * lines)
    assert solution.deflection is not None
    return per, solution.deflection


def internal_forces(attachments: Sequence[Attachment], displacements: ArrayLike,
                    stiffness: ArrayLike, load: ArrayLike = (0.0,) * 6) -> PanelForces:
    """The forces of the module docstring. ``displacements`` (N, 6): each positioner's
    attachment off where it should be (δp m at the attachment point, δθ rad; cell frame);
    ``stiffness`` (N, 2) or (2,): k_force N/m, k_couple N·m/rad, each > 0; ``load`` (6,) the
    external wrench on the panel (N; N·m about the cell origin). InputError for bad values or
    a panel the attachments do not hold."""
    n = len(attachments)
    moved = _per_attachment(displacements, n, 6, 'displacements', 'm, rad')
    k = _per_attachment(stiffness, n, 2, 'stiffness', 'N/m, N·m/rad')
    if np.any(k <= 0.0):
        raise InputError(f'stiffness {k.tolist()}: every value must be > 0')
    w = np.asarray(load, dtype=float)
    if w.shape != (6,) or not np.isfinite(w).all():
        raise InputError(f'load = {np.asarray(load).tolist()!r}: expected 6 finite numbers')
    lines, stiff, d0, owner = [], [], [], []
    for i, a in enumerate(attachments):
        rows, couples = a.wrench_lines
        for row, couple in zip(rows, couples, strict=True):
            lines.append(row)
            stiff.append(k[i, 1] if couple else k[i, 0])
            direction = row[3:] if couple else row[:3]
            d0.append(direction @ (moved[i, 3:] if couple else moved[i, :3]))
            owner.append(i)
    line_array = np.array(lines).reshape(-1, 6)
    stiff_array, d0_array = np.array(stiff), np.array(d0)
    wrenches, displacement = _solve(line_array, stiff_array, w, d0_array, owner, n)
    by_load, _ = _solve(line_array, stiff_array, w, np.zeros_like(d0_array), owner, n)
    internal = wrenches - by_load
    return PanelForces(tuple(a.name for a in attachments), wrenches, displacement, internal,
                       _pair_sizes(attachments, internal))


class PairMap(NamedTuple):
    """The internal force systems' coefficients as a linear map of the positioners'
    displacements (the internal part of :func:`internal_forces` does not depend on the load,
    and is linear in the displacements): ``pairs`` the pair (group) of each system, ``matrix``
    (S, 6N) its coefficient (N) per unit displacement (m, rad; each attachment's δp, δθ in
    the cell frame, in the attachments' order). What a watch evaluates at every reading."""

    pairs: tuple[tuple[str, ...], ...]
    matrix: FloatArray

    def sizes(self, displacements: ArrayLike) -> tuple[tuple[tuple[str, ...], float], ...]:
        """Each pair's size (N; root-sum-square of its systems' coefficients) for
        ``displacements`` (N, 6), largest first: :attr:`PanelForces.pairs`, by the map."""
        coefficients = self.matrix @ np.asarray(displacements, dtype=float).ravel()
        sizes: dict[tuple[str, ...], float] = {}
        for names, c in zip(self.pairs, coefficients, strict=True):
            sizes[names] = float(np.hypot(sizes.get(names, 0.0), c))
        return tuple(sorted(sizes.items(), key=lambda item: -item[1]))


def pair_map(attachments: Sequence[Attachment], stiffness: ArrayLike) -> PairMap:
    """The :class:`PairMap` of ``attachments`` with ``stiffness`` ((N, 2) or (2,), as
    :func:`internal_forces`): its columns are the coefficients for each unit displacement."""
    n = len(attachments)
    mobility = cell_mobility(attachments)
    pairs = tuple(tuple(names) for names in mobility.pairs_in_stress())
    columns = []
    for k in range(6 * n):
        unit = np.zeros(6 * n)
        unit[k] = 1.0
        internal = internal_forces(attachments, unit.reshape(n, 6), stiffness).internal
        columns.append(_coefficients(mobility.self_stress, internal))
    matrix = np.array(columns).T if columns else np.zeros((0, 0))
    return PairMap(pairs, matrix.reshape(len(pairs), 6 * n))


class WrenchMap(NamedTuple):
    """The attachments' wrenches on the panel, and the panel's displacement, as affine maps of
    the positioners' displacements (:func:`internal_forces` is linear in them for a given
    load): ``wrenches`` (N, 6) = ``by_load`` + (``matrix`` @ displacements.ravel()).reshape(N,
    6); the panel's (δp m of the cell origin, δθ rad) = ``moved_by_load`` + ``moved`` @
    displacements.ravel(). What the panel simulator evaluates at every true pose."""

    by_load: FloatArray
    matrix: FloatArray
    moved_by_load: FloatArray
    moved: FloatArray

    def wrenches(self, displacements: ArrayLike) -> FloatArray:
        """Each attachment's wrench on the panel (N, 6) (N; N·m about the cell origin) for
        ``displacements`` (N, 6) (m, rad; cell frame)."""
        d = np.asarray(displacements, dtype=float).ravel()
        out: FloatArray = self.by_load + (self.matrix @ d).reshape(self.by_load.shape)
        return out

    def displacement(self, displacements: ArrayLike) -> FloatArray:
        """The panel's displacement (6,) (δp m of the cell origin, δθ rad; cell frame) for
        ``displacements`` (N, 6) (m, rad; cell frame)."""
        out: FloatArray = self.moved_by_load + self.moved @ np.asarray(
            displacements, dtype=float).ravel()
        return out


def wrench_map(attachments: Sequence[Attachment], stiffness: ArrayLike,
               load: ArrayLike = (0.0,) * 6) -> WrenchMap:
    """The :class:`WrenchMap` of ``attachments`` with ``stiffness`` under ``load`` (as
    :func:`internal_forces`)."""
    n = len(attachments)
    base = internal_forces(attachments, np.zeros((n, 6)), stiffness, load)
    columns, turns = [], []
    for k in range(6 * n):
        unit = np.zeros(6 * n)
        unit[k] = 1.0
        moved = internal_forces(attachments, unit.reshape(n, 6), stiffness, load)
        columns.append((moved.wrenches - base.wrenches).ravel())
        turns.append(moved.displacement - base.displacement)
    return WrenchMap(base.wrenches, np.array(columns).T, base.displacement, np.array(turns).T)


def _coefficients(basis: FloatArray, internal: FloatArray) -> FloatArray:
    """The coefficients of ``internal`` (N, 6) on the internal force systems ``basis``."""
    if basis.shape[0] == 0:
        return np.zeros(0)
    coefficients, *_ = np.linalg.lstsq(basis.reshape(basis.shape[0], -1).T, internal.ravel(),
                                       rcond=None)
    return np.asarray(coefficients)


def _pair_sizes(attachments: Sequence[Attachment], internal: FloatArray
                ) -> tuple[tuple[tuple[str, ...], float], ...]:
    """The size (N) of the internal force systems each pair (group) carries in ``internal``:
    its coefficients on the cell's basis of internal force systems (each scaled to a largest
    force of 1), root-sum-squared per pair; largest first."""
    mobility = cell_mobility(attachments)
    if mobility.self_stress.shape[0] == 0:
        return ()
    coefficients = _coefficients(mobility.self_stress, internal)
    sizes: dict[tuple[str, ...], float] = {}
    for names, c in zip(mobility.pairs_in_stress(), coefficients, strict=True):
        key = tuple(names)
        sizes[key] = float(np.hypot(sizes.get(key, 0.0), c))
    return tuple(sorted(sizes.items(), key=lambda item: -item[1]))
