"""How a positioner's platform holds the panel: the joint between the two, as the unit twists
of the relative freedoms it leaves (seed 001 eq. 1-9: Plücker coordinates in the cell frame,
about its origin; :mod:`positioning_cell.mechanics.screw`) and, reciprocal to them, the
constraint wrenches it transmits.

Kinds (``point`` the ball centre or the clamp's reference, m, cell frame; ``direction`` unit):

- ``clamp``: rigid; no freedom, six constraint wrenches;
- ``spherical``: a ball, three rotations about ``point``; three forces through it;
- ``ball_in_slot``: a ball in a straight groove along ``direction``: three rotations and a
  translation along it; two forces through the ball, across the groove;
- ``ball_on_plane``: a ball on a flat of normal ``direction``: three rotations and two
  translations in the flat; one force along the normal.

The last two with a ball make a kinematic coupling (the 3-2-1 locating principle): a ball, a
ball in a slot and a ball on a flat fix a body exactly once, with no redundant constraint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError
from positioning_cell.mechanics.screw import (
    free_vector,
    line,
    prismatic,
    reciprocal_screws,
    spherical,
)

FloatArray = NDArray[np.float64]

CLAMP = 'clamp'
SPHERICAL = 'spherical'
BALL_IN_SLOT = 'ball_in_slot'
BALL_ON_PLANE = 'ball_on_plane'
#: The kinds, and the relative freedoms each leaves.
FREEDOMS = {CLAMP: 0, SPHERICAL: 3, BALL_IN_SLOT: 4, BALL_ON_PLANE: 5}
KINDS = tuple(FREEDOMS)


def _vector(value: ArrayLike, name: str) -> FloatArray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(f'{name} = {np.asarray(value).tolist()!r}: expected 3 finite numbers')
    return v


def _across(direction: FloatArray) -> FloatArray:
    """Two orthonormal vectors (2, 3) perpendicular to the unit ``direction``: the flat's
    slides, or the directions across a slot."""
    across: FloatArray = np.linalg.svd(direction[None])[2][1:]
    return across


@dataclass(frozen=True)
class Attachment:
    """The joint between positioner ``name``'s platform and the panel (module docstring):
    ``kind``, ``point`` (3,) m and unit ``direction`` (3,), both in the cell frame.
    InputError for an unknown kind, a point or direction not 3 finite numbers, or a zero
    direction where the kind needs one."""

    name: str
    kind: str
    point: tuple[float, ...]
    direction: tuple[float, ...] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        if self.kind not in FREEDOMS:
            raise InputError(f'attachment of {self.name}: kind {self.kind!r} is not one of '
                             f'{", ".join(KINDS)}')
        point = _vector(self.point, f'attachment of {self.name}: point')
        direction = _vector(self.direction, f'attachment of {self.name}: direction')
        norm = float(np.linalg.norm(direction))
        if self.kind in (BALL_IN_SLOT, BALL_ON_PLANE) and norm < 1e-12:
            raise InputError(f'attachment of {self.name}: a {self.kind} needs a direction, '
                             'got zero')
        object.__setattr__(self, 'point', tuple(float(v) for v in point))
        object.__setattr__(self, 'direction',
                           tuple(float(v) for v in (direction / norm if norm >= 1e-12
                                                    else direction)))

    @property
    def twists(self) -> FloatArray:
        """The relative freedoms (f, 6) of the panel on the platform, unit twists."""
        if self.kind == CLAMP:
            return np.zeros((0, 6))
        rows = [spherical(self.point)]
        d = np.asarray(self.direction)
        if self.kind == BALL_IN_SLOT:
            rows.append(prismatic(d))
        elif self.kind == BALL_ON_PLANE:
            rows += [prismatic(v) for v in _across(d)]  # the two slides in the flat
        return np.vstack(rows)

    @property
    def wrench_lines(self) -> tuple[FloatArray, FloatArray]:
        """The wrenches it carries as unit lines (k, 6) and which are couples (k,): unit forces
        through ``point`` (x, y, z for a ball and a clamp; across the slot; along the flat's
        normal), then, for a clamp, unit couples about x, y, z. They span
        :attr:`constraint_wrenches`; each is one elastic line of the internal-force model."""
        d = np.asarray(self.direction)
        if self.kind in (CLAMP, SPHERICAL):
            directions = np.eye(3)
        elif self.kind == BALL_IN_SLOT:
            directions = _across(d)
        else:
            directions = d[None]
        forces = np.array([line(s, self.point) for s in directions])
        couples = (np.array([free_vector(e) for e in np.eye(3)]) if self.kind == CLAMP
                   else np.zeros((0, 6)))
        return (np.vstack([forces, couples]),
                np.r_[np.zeros(len(forces), bool), np.ones(len(couples), bool)])

    @property
    def constraint_wrenches(self) -> FloatArray:
        """The wrenches (6 − f, 6) the attachment carries between platform and panel: a basis
        of the screws reciprocal to its freedoms (seed 001 eq. 2)."""
        return reciprocal_screws(self.twists)
