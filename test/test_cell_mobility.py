"""The mobility of a panel held by several positioners (positioning_cell.coordinated): hand-derived
cases, the screw-theory counts against the loop velocities over random cells (hypothesis), the
internal force systems as statics says they must be, the cell file and the cell_mobility tool."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from positioning_cell.config import config_path
from positioning_cell.coordinated.attachments import KINDS, Attachment
from positioning_cell.coordinated.cell_file import load
from positioning_cell.coordinated.mobility import cell_mobility, loop_mobility
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanics.screw import rank
from positioning_cell.tools import cell_mobility as tool

TRIANGLE = [(0.0, 0.0, 0.5), (1.2, 0.0, 0.5), (0.6, 0.9, 0.5)]
CENTROID = np.mean(TRIANGLE, axis=0)


def _cell(kinds: list[str], points: list[tuple[float, float, float]] = TRIANGLE,
          directions: list[tuple[float, float, float]] | None = None) -> list[Attachment]:
    directions = directions or [(0.0, 0.0, 1.0)] * len(kinds)
    return [Attachment(f'p{k + 1}', kind, p, d)
            for k, (kind, p, d) in enumerate(zip(kinds, points, directions, strict=False))]


def _toward_centroid(points: list[tuple[float, float, float]]) -> list[tuple[float, ...]]:
    return [tuple(CENTROID - np.asarray(p)) for p in points]


#: (cell, panel locked DOF, idle inputs, redundant inputs), each derived by hand: a ball leaves
#: the platform 3 turns and carries 3 forces; two balls leave the turn about their line and one
#: force along it in stress; three balls fix the panel with the three side forces in stress; a
#: clamp carries 6, so three over-constrain by 18 - 6; the 3-2-1 and Maxwell couplings fix it
#: with exactly 6 constraints; three vertical slots carry 6 horizontal forces, which span only
#: the horizontal force and the moment about z (3): the panel keeps 3 freedoms (rise, tilt
#: about x and y) and 3 forces are in stress.
CASES = {
    'one ball': (_cell(['spherical'], TRIANGLE[:1]), 3, 3, 0),
    'one clamp': (_cell(['clamp'], TRIANGLE[:1]), 0, 0, 0),
    'two balls': (_cell(['spherical'] * 2, TRIANGLE[:2]), 1, 6, 1),
    'three balls': (_cell(['spherical'] * 3), 0, 9, 3),
    'three balls in a line': (_cell(['spherical'] * 3, [(0.0, 0.0, 0.5), (1.0, 0.0, 0.5),
                                                        (2.0, 0.0, 0.5)]), 1, 9, 4),
    'three clamps': (_cell(['clamp'] * 3), 0, 0, 12),
    '3-2-1 coupling': (_cell(['spherical', 'ball_in_slot', 'ball_on_plane'],
                             directions=[(0.0, 0.0, 1.0), (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)]),
                       0, 12, 0),
    'Maxwell coupling': (_cell(['ball_in_slot'] * 3, directions=_toward_centroid(TRIANGLE)),
                         0, 12, 0),
    'three vertical slots': (_cell(['ball_in_slot'] * 3), 3, 12, 3),
    'four balls': (_cell(['spherical'] * 4, [*TRIANGLE, (1.0, 1.0, 0.6)]), 0, 12, 6),
}


@pytest.mark.parametrize('name', list(CASES))
def test_hand_derived_cells(name: str) -> None:
    attachments, locked, idle, redundant = CASES[name]
    found = cell_mobility(attachments)
    assert (found.locked_dof, found.idle_inputs, found.redundant_inputs) == (
        locked, idle, redundant), found.lines()
    assert found.panel_dof == 6 and found.inputs == 6 * len(attachments)
    assert found.over_constrained == (redundant > 0)
    loops = loop_mobility(attachments)
    assert loops.redundant_inputs(found.inputs) == redundant
    assert (loops.idle_inputs, loops.panel_motions) == (idle, 6)


def test_three_balls_stress_the_panel_along_its_sides() -> None:
    """Each internal force system of three balls is one pair pulling along the line between
    its balls, as statics says (a two-force member), and every system is in equilibrium."""
    found = cell_mobility(CASES['three balls'][0])
    assert sorted(found.pairs_in_stress()) == [['p1', 'p2'], ['p1', 'p3'], ['p2', 'p3']]
    for state, pair in zip(found.self_stress, found.pairs_in_stress(), strict=True):
        np.testing.assert_allclose(state.sum(axis=0), 0.0, atol=1e-12)  # equilibrium
        i, j = (int(name[1:]) - 1 for name in pair)
        side = np.subtract(TRIANGLE[j], TRIANGLE[i])
        force = state[i, :3]
        assert np.linalg.norm(np.cross(force, side)) < 1e-12 * np.linalg.norm(side)
        np.testing.assert_allclose(state[i, 3:], np.cross(TRIANGLE[i], force), atol=1e-12)


@st.composite
def cells(draw: st.DrawFn) -> list[Attachment]:
    n = draw(st.integers(1, 4))
    unit = st.floats(-1.0, 1.0, allow_nan=False)
    out = []
    for k in range(n):
        point = tuple(draw(unit) for _ in range(3))
        direction = tuple(draw(unit) for _ in range(3))
        kind = draw(st.sampled_from(KINDS))
        if kind in ('ball_in_slot', 'ball_on_plane') and np.linalg.norm(direction) < 0.1:
            direction = (0.0, 0.0, 1.0)
        out.append(Attachment(f'p{k}', kind, point, direction))
    return out


@settings(max_examples=150, deadline=None)
@given(cells())
def test_screw_theory_and_loop_velocities_agree_on_any_cell(attachments: list[Attachment]
                                                            ) -> None:
    found = cell_mobility(attachments)
    loops = loop_mobility(attachments)
    assert loops.redundant_inputs(found.inputs) == found.redundant_inputs
    assert (loops.idle_inputs, loops.panel_motions) == (found.idle_inputs, found.panel_dof)
    assert found.inputs == (6 - found.locked_dof) + found.idle_inputs + found.redundant_inputs
    # the internal force systems: independent, in equilibrium, each attachment's wrench one it
    # can carry
    states = found.self_stress
    assert states.shape[0] == found.redundant_inputs
    if states.size:
        assert rank(states.reshape(states.shape[0], -1)) == states.shape[0]
        np.testing.assert_allclose(states.sum(axis=1), 0.0, atol=1e-9)
    for k, a in enumerate(attachments):
        carried = a.constraint_wrenches
        for state in states:
            assert rank(np.vstack([carried, state[k]])) == rank(carried)


def test_bad_attachments_are_refused() -> None:
    with pytest.raises(InputError, match="kind 'hinge'"):
        Attachment('p1', 'hinge', (0.0, 0.0, 0.0))
    with pytest.raises(InputError, match='needs a direction'):
        Attachment('p1', 'ball_in_slot', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    with pytest.raises(InputError, match='finite'):
        Attachment('p1', 'spherical', (0.0, float('nan'), 0.0))
    with pytest.raises(InputError, match='no attachment'):
        cell_mobility([])
    with pytest.raises(InputError, match='repeat'):
        cell_mobility(_cell(['spherical'] * 2, [TRIANGLE[0]] * 2)[:1] * 2)


def test_the_shipped_cell_puts_each_ball_where_its_platform_is_at_home() -> None:
    cell = load(config_path(tool.DEFAULT_CELL))
    mech = Mechanism.default()
    points = [a.point for a in cell.attachments(mech)]
    expected = [np.asarray(e.base_position) + mech.home_position + np.asarray(e.offset)
                for e in cell.positioners]  # identity base orientations
    np.testing.assert_allclose(points, expected, atol=1e-15)
    assert [e.kind for e in cell.positioners] == ['spherical'] * 3


@pytest.mark.parametrize(('edit', 'words'), [
    (lambda t: t.replace('kind: spherical', 'kind: hinge', 1),
     "positioner p1.attachment: .*'hinge'"),
    (lambda t: t.replace('[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]',
                         '[0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 1.0]', 1), 'p1.base: the quaternion'),
    (lambda t: t.replace('name: p2', 'name: p1'), 'names repeat'),
    (lambda t: t.replace('name: p2', 'nom: p2'), r'positioners\[1\]: keys must be'),
    (lambda t: t.replace('offset: [0.0, 0.0, 0.05]', 'offset: [0.0, .nan, 0.05]', 1),
     'offset: .* not finite'),
    (lambda t: 'cell: {positioners: []}\n', '1 to 4 positioners'),
    (lambda t: t.replace('cell:', 'cel:'), 'one key `cell`'),
])
def test_a_bad_cell_file_is_refused_naming_what(tmp_path: Path, edit: object,
                                                words: str) -> None:
    text = config_path(tool.DEFAULT_CELL).read_text()
    path = tmp_path / 'cell.yaml'
    path.write_text(edit(text))  # type: ignore[operator]
    with pytest.raises(ConfigError, match=words):
        load(path)
    assert tool.main(['--cell', str(path)]) == 2


def test_the_tool_reports_the_shipped_cell_and_the_alternatives(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert tool.main([]) == 0
    out = capsys.readouterr().out
    assert 'inputs 18 = 6 moving the panel + 9 idle + 3 redundant' in out
    assert 'p1 - p2: 1 internal force system(s)' in out
    assert tool.main(['--json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['mobility']['redundant_inputs'] == 3 and doc['mobility']['over_constrained']
    alternatives = doc['alternatives']
    assert alternatives['all clamp']['redundant_inputs'] == 12
    for exact in ('all ball_in_slot', '3-2-1 coupling (ball, slot, flats)'):
        assert alternatives[exact]['redundant_inputs'] == 0, exact
        assert alternatives[exact]['locked_dof'] == 0, exact


def test_the_tool_stacks_the_positioners_errors_up_on_the_panel(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The tolerance engine's figures of the shipped cell (three balls): 10 µm on each
    positioner moves the centroid by at most 10 µm and by 10/√3 µm RSS per axis, each
    positioner a third of it; a bad figure is refused (exit 2)."""
    assert tool.main(['--error-um', '10']) == 0
    out = capsys.readouterr().out
    assert 'each positioner off by at most 10 um' in out
    assert 'test_point.x (um)            10.00      5.77     33%    33%    33%' in out
    assert tool.main(['--json', '--error-um', '5']) == 0
    doc = json.loads(capsys.readouterr().out)['tolerance']
    assert doc['error_m'] == pytest.approx(5e-6) and doc['positioners'] == ['p1', 'p2', 'p3']
    assert doc['outputs']['test_point.z']['rss'] == pytest.approx(5e-6 / 3**0.5, rel=1e-9)
    assert set(doc['outputs']) >= {'force p1-p2', 'force p1-p3', 'force p2-p3'}
    assert tool.main(['--error-um', '-1']) == 2
    assert 'each must be finite and >= 0' in capsys.readouterr().err
