"""``cell_mobility``: the mobility of a panel held by several positioners (issue 27 item 2).

Reads a cell file (``--cell``, default the shipped ``config/three_positioners.yaml``;
:mod:`positioning_cell.coordinated.cell_file`) and prints, by screw theory (seed 001 §3;
:mod:`positioning_cell.coordinated.mobility`): the inputs split into those moving the panel,
the idle and the redundant ones, whether every input locked holds the panel, and the
internal force systems pair by pair; then, for the same attachment points, which attachment
types make the cell over-constrained (each kind for every positioner, and the 3-2-1 kinematic
coupling: a ball, a ball in a slot toward it, balls on flats; slots of every positioner
point at the centroid, Maxwell's coupling). Each analysis is checked by the
loop velocities (a mismatch exits 1). Then the tolerance engine on the assembled loops
(:mod:`positioning_cell.coordinated.panel_tolerance`): how far each positioner's error
(``--error-um``, a clamp's turn ``--turn-urad``) moves the panel's test point and turns it,
and loads each pair, worst case and root-sum-square, and each positioner's share. ``--json``
prints one JSON document instead. Exit
status (:mod:`positioning_cell.tools.exits`): 0 done, 1 the two analyses disagree, 2 a bad
cell file.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from positioning_cell.config import config_path
from positioning_cell.coordinated.attachments import (
    BALL_IN_SLOT,
    BALL_ON_PLANE,
    CLAMP,
    KINDS,
    SPHERICAL,
    Attachment,
)
from positioning_cell.coordinated.cell_file import load
from positioning_cell.coordinated.mobility import CellMobility, cell_mobility, loop_mobility
from positioning_cell.coordinated.panel_tolerance import (
    panel_sensitivity,
    panel_stackup,
    stackup_lines,
)
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.tools.exits import Exit, exit_table

#: The shipped cell file.
DEFAULT_CELL = 'three_positioners.yaml'


def kinematic_coupling(attachments: Sequence[Attachment]) -> list[Attachment]:
    """The 3-2-1 arrangement at the same points: the first a ball, the second a ball in a slot
    pointing at the first, the others balls on flats normal to the cell's z."""
    first = np.asarray(attachments[0].point)
    out = [Attachment(attachments[0].name, SPHERICAL, attachments[0].point)]
    for k, a in enumerate(attachments[1:], start=1):
        toward = first - np.asarray(a.point)
        kind, direction = ((BALL_IN_SLOT, tuple(toward)) if k == 1 else
                           (BALL_ON_PLANE, (0.0, 0.0, 1.0)))
        out.append(Attachment(a.name, kind, a.point, direction))
    return out


def alternatives(attachments: Sequence[Attachment]) -> dict[str, list[Attachment]]:
    """The same points with every positioner on one kind (slots pointing at the points'
    centroid, Maxwell's coupling; flats normal to the cell's z), and the 3-2-1 coupling
    (N ≥ 2)."""
    centroid = np.mean([a.point for a in attachments], axis=0)

    def direction(kind: str, a: Attachment) -> tuple[float, ...]:
        toward = centroid - np.asarray(a.point)
        if kind == BALL_IN_SLOT and np.linalg.norm(toward) > 1e-9:
            return tuple(toward)
        return (0.0, 0.0, 1.0)

    out = {f'all {kind}': [Attachment(a.name, kind, a.point, direction(kind, a))
                           for a in attachments] for kind in KINDS}
    if len(attachments) >= 2:
        out['3-2-1 coupling (ball, slot, flats)'] = kinematic_coupling(attachments)
    return out


def checked(attachments: Sequence[Attachment]) -> CellMobility:
    """:func:`cell_mobility`, with the loop velocities giving the same counts (else
    RuntimeError naming both)."""
    found = cell_mobility(attachments)
    loops = loop_mobility(attachments)
    if (loops.redundant_inputs(found.inputs), loops.idle_inputs, loops.panel_motions) != (
            found.redundant_inputs, found.idle_inputs, found.panel_dof):
        raise RuntimeError(f'screw theory {found.document()} and loop velocities {loops} '
                           'disagree')
    return found


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``cell_mobility [--cell FILE] [--json]``."""
    parser = argparse.ArgumentParser(
        prog='cell_mobility', description='Mobility of a panel held by several positioners: '
        'idle and redundant inputs, internal force systems, which attachment types '
        'over-constrain the cell (screw theory, seed 001).',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--cell', type=Path, help='cell file (default: the shipped '
                        f'config/{DEFAULT_CELL})')
    parser.add_argument('--error-um', type=float, default=10.0, help="each positioner's "
                        'attachment off by at most this, um (default 10)')
    parser.add_argument('--turn-urad', type=float, default=20.0, help="a clamp's turn off "
                        'by at most this, urad (default 20)')
    parser.add_argument('--json', action='store_true', help='one JSON document')
    args = parser.parse_args(argv)
    error, turn = args.error_um * 1e-6, args.turn_urad * 1e-6
    try:
        cell = load(args.cell if args.cell is not None else config_path(DEFAULT_CELL))
        attachments = cell.attachments()
    except ConfigError as err:
        print(f'cell_mobility: {err}', file=sys.stderr)
        return Exit.USAGE
    try:
        stack = panel_stackup(panel_sensitivity(cell, None), error, turn)
    except InputError as err:
        print(f'cell_mobility: {err}', file=sys.stderr)
        return Exit.USAGE
    try:
        found = checked(attachments)
        others = {name: checked(a) for name, a in alternatives(attachments).items()}
    except RuntimeError as err:
        print(f'cell_mobility: {err}', file=sys.stderr)
        return Exit.NOT_ACHIEVED
    if args.json:
        tolerance = {'error_m': error, 'turn_rad': turn, 'positioners': stack.positioners,
                     'outputs': {o: {'worst': float(stack.worst[k]), 'rss': float(stack.rss[k]),
                                     'shares': stack.shares[k].tolist()}
                                 for k, o in enumerate(stack.outputs)}}
        print(json.dumps({'cell': str(cell.path), 'mobility': found.document(),
                          'alternatives': {k: v.document() for k, v in others.items()},
                          'tolerance': tolerance}, indent=2))
        return Exit.OK
    print(f'{cell.path}:')
    print('\n'.join(f'  {line}' for line in found.lines()))
    print('the same attachment points with other attachments:')
    print(f'  {"attachments":<38} {"held":>5} {"idle":>5} {"redundant":>9}  over-constrained')
    for name, m in others.items():
        print(f'  {name:<38} {"yes" if m.locked_dof == 0 else "no":>5} {m.idle_inputs:>5} '
              f'{m.redundant_inputs:>9}  {"yes" if m.over_constrained else "no"}')
    clamped = any(a.kind == CLAMP for a in attachments)
    print('\n'.join(stackup_lines(stack, error, turn if clamped else 0.0)))
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
