"""How each positioner's error moves the panel and loads it (issue 27 item 6): the tolerance
engine applied to the assembled loops.

The sources are each positioner's attachment off where it should be: its translation δp
(m, cell frame; ``p1.x``, ``p1.y``, ``p1.z``) and, for a clamp, which holds the panel's turn
too, its turn δθ (rad; ``p1.rx`` ...). Seed 002's compatibility is linear in them
(:func:`~.internal_forces.wrench_map`, :func:`~.internal_forces.pair_map`), so its maps are
the first-order model T = ∂outputs/∂sources of seed 004 eq. 14 without a loop solve:

- the panel's test point (``test_point.x`` ...; m, cell frame): the panel's displacement
  (δp of the cell origin, δθ) taken to the point, δp + δθ × c;
- the panel's turn (``panel.rx`` ...; rad);
- each internal force system's coefficient (``force p1-p2``, N; its largest force per unit
  coefficient is 1: :mod:`.internal_forces`), one per pair of attachments for balls.

Their stack-ups are the engine's (:mod:`positioning_cell.tolerance.stackup`): the worst case
with each positioner's translation error a ball of radius ``error`` (seed 004 eq. 15 over
balls) and a clamp's turn a ball of ``turn``, the root-sum-square with the same figures as
standard deviations per axis, and each positioner's share of each output's variance. The
maps are built about the panel at home: the figures hold for the small moves of a positioning
cell (millimetres, milliradians; ``test_panel_tolerance`` checks them against the simulator's
nonlinear panel by Monte Carlo).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.attachments import CLAMP
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.internal_forces import pair_map, wrench_map
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.tolerance.stackup import root_sum_square, worst_case

FloatArray = NDArray[np.float64]
#: The translation sources' and the turn sources' axes.
AXES = ('x', 'y', 'z')
TURNS = ('rx', 'ry', 'rz')


class PanelSensitivity(NamedTuple):
    """T (module docstring): ``matrix`` (R, S), outputs per unit source; ``sources`` and
    ``outputs`` their names; ``owners`` (S,) each source's positioner; ``turns`` (S,) True for
    a clamp's turn (rad), False for a translation (m)."""

    sources: tuple[str, ...]
    outputs: tuple[str, ...]
    owners: tuple[str, ...]
    turns: NDArray[np.bool_]
    matrix: FloatArray

    def rows(self, prefix: str) -> FloatArray:
        """The rows of the outputs named ``prefix``... (R', S)."""
        out: FloatArray = self.matrix[[k for k, name in enumerate(self.outputs)
                                       if name.startswith(prefix)]]
        return out


def panel_sensitivity(cell: CellFile, mech: Mechanism | None = None,
                      point: ArrayLike | None = None) -> PanelSensitivity:
    """T of ``cell`` (module docstring) whose positioners' machine is ``mech`` (default seed
    000's) at the test ``point`` (3,) m, cell frame at home (default its ISO 9283 test point,
    :meth:`~.cell_file.CellFile.test_point`)."""
    attachments = cell.attachments(mech)
    c = cell.test_point(mech) if point is None else np.asarray(point, dtype=float)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise InputError(f'test point: expected 3 finite numbers (m), got {c.tolist()!r}')
    moves = wrench_map(attachments, cell.panel.stiffness, cell.panel.weight()).moved
    systems = pair_map(attachments, cell.panel.stiffness)
    columns, sources, owners, turns = [], [], [], []
    for i, a in enumerate(attachments):
        kept = [(AXES, 0)] + ([(TURNS, 3)] if a.kind == CLAMP else [])
        for axes, first in kept:
            for j, axis in enumerate(axes):
                columns.append(6 * i + first + j)
                sources.append(f'{a.name}.{axis}')
                owners.append(a.name)
                turns.append(first == 3)
    panel = moves[:, columns]  # (6, S): δp of the cell origin, δθ
    at_point = panel[:3] + np.cross(panel[3:].T, c).T  # δp + δθ × c
    forces = systems.matrix[:, columns]
    names = [' '.join(('force', '-'.join(pair))) for pair in systems.pairs]
    repeated = {n for n in names if names.count(n) > 1}
    counts: dict[str, int] = {}
    for k, n in enumerate(names):  # a pair with several systems (clamps): numbered
        if n in repeated:
            counts[n] = counts.get(n, 0) + 1
            names[k] = f'{n} #{counts[n]}'
    outputs = (*(f'test_point.{a}' for a in AXES), *(f'panel.{a}' for a in TURNS), *names)
    return PanelSensitivity(tuple(sources), outputs, tuple(owners), np.array(turns),
                            np.vstack([at_point, panel[3:], forces]))


class PanelStackup(NamedTuple):
    """The stack-ups of each output (module docstring): ``worst`` (R,) and ``rss`` (R,) in its
    unit, ``shares`` (R, N) each positioner's share of its variance (rows sum to 1; 0 for an
    output no source moves), ``positioners`` their names."""

    outputs: tuple[str, ...]
    worst: FloatArray
    rss: FloatArray
    positioners: tuple[str, ...]
    shares: FloatArray


def panel_stackup(sensitivity: PanelSensitivity, error: float, turn: float = 0.0
                  ) -> PanelStackup:
    """Stack-ups of ``sensitivity`` with each positioner's attachment off by at most ``error``
    m (its translation: a ball) and a clamp's turn by ``turn`` rad (a ball), and the same
    figures as standard deviations per axis for the root-sum-square (module docstring)."""
    if not (np.isfinite(error) and np.isfinite(turn) and error >= 0.0 and turn >= 0.0):
        raise InputError(f'error {error:g} m and turn {turn:g} rad: each must be finite '
                         'and >= 0')
    s = sensitivity
    scale = np.where(s.turns, turn, error)
    balls = tuple((k, k + 3) for k in range(0, len(s.sources), 3))
    worst = worst_case(s.matrix, scale, balls)
    rss = root_sum_square(s.matrix, scale)
    positioners = tuple(dict.fromkeys(s.owners))
    variance = (s.matrix * scale) ** 2
    per = np.array([variance[:, [o == p for o in s.owners]].sum(axis=1)
                    for p in positioners]).T
    total = per.sum(axis=1, keepdims=True)
    shares = np.divide(per, total, out=np.zeros_like(per), where=total > 0.0)
    return PanelStackup(s.outputs, worst, rss, positioners, shares)


def stackup_lines(stackup: PanelStackup, error: float, turn: float = 0.0) -> list[str]:
    """The stack-up as a table: each output's worst case and RSS (µm, µrad, N) and each
    positioner's share of its variance."""
    head = (f'each positioner off by at most {error * 1e6:g} um'
            + (f', a clamp turned by at most {turn * 1e6:g} urad' if turn else '')
            + ' (the RSS: the same as standard deviations per axis):')
    names = stackup.positioners
    lines = [head, f'  {"output":<24} {"worst":>9} {"RSS":>9}  '
             + ' '.join(f'{n:>6}' for n in names)]
    for k, output in enumerate(stackup.outputs):
        unit, factor = (('N', 1.0) if output.startswith('force') else
                        ('urad', 1e6) if output.startswith('panel.') else ('um', 1e6))
        lines.append(f'  {output + " (" + unit + ")":<24} {stackup.worst[k] * factor:>9.2f} '
                     f'{stackup.rss[k] * factor:>9.2f}  '
                     + ' '.join(f'{share:>6.0%}' for share in stackup.shares[k]))
    return lines


def sampled_errors(sensitivity: PanelSensitivity, error: float, turn: float, count: int,
                   rng: np.random.Generator) -> FloatArray:
    """``count`` draws (count, S) of the sources with standard deviations ``error`` m per
    translation axis and ``turn`` rad per turn axis (what :func:`panel_stackup`'s RSS
    takes)."""
    scale = np.where(sensitivity.turns, turn, error)
    out: FloatArray = rng.standard_normal((count, len(sensitivity.sources))) * scale
    return out


def by_positioner(sensitivity: PanelSensitivity, draws: ArrayLike,
                  names: Sequence[str]) -> FloatArray:
    """``draws`` (K, S) as each positioner's attachment displacement (K, N, 6) (δp m, δθ rad;
    cell frame) in the order ``names``: the displacements the maps take."""
    d = np.asarray(draws, dtype=float)
    out = np.zeros((d.shape[0], len(names), 6))
    for k, (owner, turn) in enumerate(zip(sensitivity.owners, sensitivity.turns,
                                          strict=True)):
        axis = sensitivity.sources[k].split('.')[-1]
        column = (TURNS.index(axis) + 3) if turn else AXES.index(axis)
        out[:, list(names).index(owner), column] = d[:, k]
    return out
