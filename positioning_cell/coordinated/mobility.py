"""The mobility of a panel held by N positioners (issue 27 item 2): seed 001's screw-theory
method (§3: each limb's twist system, its reciprocal constraint wrenches, DOF = 6 − rank)
applied to the assembled cell, and checked by a velocity analysis of its closed loops.

Each positioner is a 6-DOF parallel machine (six actuated inputs: its leg lengths and second U
angles), so its platform can take any small twist; the panel hangs on the N platforms through
their attachments (:mod:`.attachments`). Seen from the panel, positioner i with its
attachment is one limb whose twist system is the platform's six freedoms and the
attachment's f_i; with every positioner locked, only the attachments' freedoms remain, and
their constraint wrenches W_i (6 − f_i each) hold the panel. Then (all counts integers):

- ``panel_dof``: the panel's freedom with the positioners driving (6 − rank of the limbs'
  constraints: 6 while one positioner holds it);
- ``locked_dof`` = 6 − rank(W): what the panel can still do with every input locked (0: the
  cell holds it);
- ``redundant_inputs`` = Σ(6 − f_i) − rank(W): the over-constraint, the number of independent
  internal force systems (self-stress states: attachment wrenches summing to zero) that
  inputs moved out of agreement set up in the panel; the cell is over-constrained when > 0;
- ``idle_inputs``: input motions the panel does not see (a platform turning about its ball);
- and 6N = (6 − locked_dof) + idle_inputs + redundant_inputs.

The velocity check (:func:`loop_mobility`) does not use the wrenches: the unknowns are the
panel's twist, the N platform twists (the inputs, through each positioner's invertible
Jacobian) and the attachments' joint rates, tied by one loop equation per attachment
(panel twist = platform twist + attachment's twist); the dimensions of the solution space
projected onto the inputs and onto the panel give the same counts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from positioning_cell.coordinated.attachments import Attachment
from positioning_cell.errors import InputError
from positioning_cell.mechanics.screw import (
    Limb,
    mobility,
    null_space_rows,
    rank,
)

FloatArray = NDArray[np.float64]

#: Inputs of one positioner (3 leg lengths, 3 second U angles).
INPUTS_PER_POSITIONER = 6
#: The six unit twists of a rigid body's freedom about the cell origin (rotations, translations).
_FULL = np.eye(6)


@dataclass(frozen=True)
class CellMobility:
    """The assembled cell's mobility (module docstring). ``self_stress`` (s, N, 6): a basis of
    the internal force systems, each the wrench every attachment puts on the panel (about the
    cell origin; Σ over the N attachments = 0), scaled so that its largest force is 1; taken
    pair by pair where the pairs span them (each system then loads two attachments, the pair
    that disagrees when it grows), else a general basis."""

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    inputs: int
    panel_dof: int
    locked_dof: int
    idle_inputs: int
    redundant_inputs: int
    self_stress: FloatArray

    @property
    def over_constrained(self) -> bool:
        """True when the inputs can strain the panel (a redundant input)."""
        return self.redundant_inputs > 0

    def pairs_in_stress(self, tolerance: float = 1e-9) -> list[list[str]]:
        """Per internal force system, the attachments it loads (their names)."""
        return [[n for n, w in zip(self.names, state, strict=True)
                 if np.linalg.norm(w) > tolerance] for state in self.self_stress]

    def lines(self) -> list[str]:
        """For people: the counts and what they mean."""
        n = len(self.names)
        held = ('held: no freedom with every input locked' if self.locked_dof == 0 else
                f'NOT held: {self.locked_dof} freedom(s) left with every input locked')
        verdict = (f'over-constrained: {self.redundant_inputs} redundant input(s), as many '
                   'independent internal force systems in the panel' if self.over_constrained
                   else 'not over-constrained: no input can strain the panel')
        pairs: dict[str, int] = {}
        for loaded in self.pairs_in_stress():
            key = ' - '.join(loaded)
            pairs[key] = pairs.get(key, 0) + 1
        systems = [f'  {key}: {k} internal force system(s)' for key, k in pairs.items()]
        return [f'{n} positioners, attachments: {", ".join(self.kinds)}',
                f'inputs {self.inputs} = {6 - self.locked_dof} moving the panel + '
                f'{self.idle_inputs} idle + {self.redundant_inputs} redundant',
                f'panel: {self.panel_dof} DOF with the positioners driving; {held}',
                verdict, *systems]

    def document(self) -> dict[str, object]:
        """For JSON."""
        return {'positioners': list(self.names), 'attachments': list(self.kinds),
                'inputs': self.inputs, 'panel_dof': self.panel_dof,
                'locked_dof': self.locked_dof, 'idle_inputs': self.idle_inputs,
                'redundant_inputs': self.redundant_inputs,
                'over_constrained': self.over_constrained,
                'internal_force_systems': self.pairs_in_stress()}


def _limbs(attachments: Sequence[Attachment]) -> list[Limb]:
    """Each positioner with its attachment as one limb of the panel: the platform's six
    freedoms (actuated), then the attachment's (passive)."""
    return [Limb(a.name, np.vstack([_FULL, a.twists]),
                 np.r_[np.ones(6, bool), np.zeros(a.twists.shape[0], bool)], a.kind)
            for a in attachments]


def cell_mobility(attachments: Sequence[Attachment]) -> CellMobility:
    """The mobility of the panel held through ``attachments`` (one per positioner, N ≥ 1) by
    screw theory (module docstring). InputError for no attachment or a repeated name."""
    if not attachments:
        raise InputError('cell mobility: no attachment (one per positioner)')
    names = tuple(a.name for a in attachments)
    if len(set(names)) != len(names):
        raise InputError(f'cell mobility: positioner names repeat: {list(names)}')
    panel = mobility(_limbs(attachments))
    held = [a.constraint_wrenches for a in attachments]
    stacked = np.vstack(held)
    rank_locked = rank(stacked)
    counts = [w.shape[0] for w in held]
    per_attachment = _self_stress(held, sum(counts) - rank_locked)
    idle = sum(a.twists.shape[0] for a in attachments)  # each freedom an input may take
    return CellMobility(names, tuple(a.kind for a in attachments),
                        INPUTS_PER_POSITIONER * len(attachments), panel.dof, 6 - rank_locked,
                        idle, sum(counts) - rank_locked, per_attachment)


def _states(held: Sequence[FloatArray], members: Sequence[int]) -> FloatArray:
    """Self-stress states (s, N, 6) that load only the attachments ``members``: λ with
    Σ_k λ_k w_k = 0 over their stacked constraint wrenches, as each attachment's wrench."""
    stacked = np.vstack([held[k] for k in members])
    states = null_space_rows(stacked.T)
    out = np.zeros((states.shape[0], len(held), 6))
    start = 0
    for k in members:
        stop = start + held[k].shape[0]
        out[:, k] = states[:, start:stop] @ held[k]
        start = stop
    return out


def _self_stress(held: Sequence[FloatArray], count: int) -> FloatArray:
    """A basis (count, N, 6) of the internal force systems: pair by pair (greedy, independent)
    when the pairs span them, else the null space of all the constraint wrenches."""
    chosen: list[FloatArray] = []
    for i in range(len(held)):
        for j in range(i + 1, len(held)):
            for state in _states(held, (i, j)):
                if rank(np.array([*chosen, state]).reshape(len(chosen) + 1, -1)) > len(chosen):
                    chosen.append(state)
    basis = (np.array(chosen).reshape(-1, len(held), 6) if len(chosen) == count
             else _states(held, range(len(held))))
    scale = np.linalg.norm(basis[..., :3], axis=2).max(axis=1, initial=0.0)
    scaled: FloatArray = basis / np.where(scale > 0.0, scale, 1.0)[:, None, None]
    return scaled


@dataclass(frozen=True)
class LoopMobility:
    """The same counts from the loop equations' velocities (module docstring): the dimensions
    of the compatible inputs, of the panel's motions, and of the input motions with the panel
    still."""

    compatible_inputs: int
    panel_motions: int
    idle_inputs: int

    def redundant_inputs(self, inputs: int) -> int:
        """Inputs that cannot move independently: ``inputs`` − compatible ones."""
        return inputs - self.compatible_inputs


def loop_mobility(attachments: Sequence[Attachment]) -> LoopMobility:
    """The velocity analysis of the closed loops: unknowns x = (panel twist 6, platform twists
    6N, attachment rates Σf), one loop per attachment: panel twist − platform twist −
    Σ rate·twist = 0 (6 rows); dimensions of the solutions projected onto the platform twists
    and onto the panel twist, and of those with the panel still."""
    n = len(attachments)
    freedoms = [a.twists for a in attachments]
    f_total = sum(t.shape[0] for t in freedoms)
    width = 6 + 6 * n + f_total
    loops = np.zeros((6 * n, width))
    column = 6 + 6 * n
    for i, twists in enumerate(freedoms):
        rows = slice(6 * i, 6 * i + 6)
        loops[rows, :6] = np.eye(6)
        loops[rows, 6 + 6 * i:12 + 6 * i] = -np.eye(6)
        loops[rows, column:column + twists.shape[0]] = -twists.T
        column += twists.shape[0]
    solutions = null_space_rows(loops)  # (M, width): every compatible velocity
    inputs = solutions[:, 6:6 + 6 * n]
    panel = solutions[:, :6]
    still = null_space_rows(np.vstack([loops, np.eye(6, width)]))
    return LoopMobility(rank(inputs) if inputs.size else 0, rank(panel) if panel.size else 0,
                        rank(still[:, 6:6 + 6 * n]) if still.size else 0)

