"""The live view's panel view without ROS (issue 27 item 6): the Foxglove messages
(positioning_cell.nodes.live_view_panel) of a panel snapshot, checked against the panel
simulator's truth and the cell file: the force arrows are the truth's internal forces (within
2 %), coloured by the limit; the panel is drawn where it is measured; the bases where the file
puts them; what is missing is left out and said. On the running cell: test_coordinated_cell."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from foxglove_ws import as_dict
from scipy.spatial.transform import Rotation
from test_panel_watch import NAMES, NOW, SETTINGS, _strained

from positioning_cell import names
from positioning_cell.coordinated.panel_motion import bases, platform_goals
from positioning_cell.core.kinematics import platform_points
from positioning_cell.nodes.live_view_panel import (
    FORCE_COLOURS,
    base_frame,
    force_colour,
    panel_scene,
    panel_status_document,
    panel_status_schema,
    panel_transforms,
)
from positioning_cell.sim.panel import PanelTruth
from positioning_cell.watch.panel import PanelWatchState
from positioning_cell.watch.state import Status

CELL = SETTINGS.cell()
MECH = SETTINGS.mechanism
PANEL_P = np.array([0.001, -0.002, 0.003])
PANEL_Q = Rotation.from_rotvec([0.0, 0.0, 0.004]).as_quat()


def _entities(update: object) -> dict[str, dict[str, Any]]:
    return {e['id']: e for e in as_dict(update)['entities']}


def _state(strained: bool = True) -> PanelWatchState:
    state = PanelWatchState()
    state.coordinator_settings(SETTINGS)
    state.coordinator(Status(0, 'idle', NOW))
    state.panel((PANEL_P, PANEL_Q), NOW - 0.2)
    joints, efforts, _ = _strained()
    for name, q, tau in zip(NAMES, joints, efforts, strict=True):
        state.joints(name, q, tau)
    state.set_status('p1', positioner=Status(0, 'settled', NOW), drives=Status(0, 'ok', NOW))
    return state


def test_the_force_arrows_are_the_truths_internal_forces() -> None:
    """p2 0.2 mm and p3 0.1 mm off the rigid panel: each arrow starts at its ball where the
    panel is measured, points along the truth's internal force there and is force_scale m
    per newton of it; its label names the positioner and the force."""
    snapshot = _state().snapshot()
    scale = 2e-3
    scene = _entities(panel_scene(snapshot, NOW, scale))
    assert set(scene) == {'bases', 'positioners', 'panel', 'forces'}
    goals = [(p + d, q) for (p, q), d in zip(
        platform_goals(CELL, MECH, np.zeros(3), [0.0, 0.0, 0.0, 1.0]),
        np.array([[0.0, 0.0, 0.0], [2e-4, 0.0, 0.0], [0.0, 1e-4, 0.0]]), strict=True)]
    truth = PanelTruth(CELL, MECH).state(goals)
    # each positioner's legs and platform where its encoders put them (the strained platforms)
    drawn = scene['positioners']['lines']
    assert len(drawn[0]['points']) == 2 * 3 * len(NAMES)  # a line per leg
    for (p, q), base, top in zip(goals, bases(CELL), drawn[1:], strict=True):
        corners = base.apply(platform_points(MECH, p[None], np.asarray(q)[None])[0])
        got = np.array([[c['x'], c['y'], c['z']] for c in top['points'][:3]])
        np.testing.assert_allclose(got, corners, atol=1e-9)
    forces = scene['forces']
    balls = Rotation.from_quat(PANEL_Q).apply(CELL.panel_points(MECH)) + PANEL_P
    sizes = []
    for name, ball, arrow, text in zip(NAMES, balls, forces['arrows'], forces['texts'],
                                       strict=True):
        start = arrow['pose']['position']
        assert [start['x'], start['y'], start['z']] == pytest.approx(ball.tolist(), abs=1e-12)
        length = arrow['shaft_length'] + arrow['head_length']
        sizes.append(length / scale)
        assert text['text'] == f'{name} {length / scale:.0f} N'
    assert truth.largest > 100.0 and max(sizes) == pytest.approx(truth.largest, rel=0.02)
    # each along its force (foxglove's arrows point along their pose's +x)
    internal = snapshot.forces()
    assert not isinstance(internal, str)
    for arrow, force in zip(forces['arrows'], internal.internal, strict=True):
        q = arrow['pose']['orientation']
        along = Rotation.from_quat([q['x'], q['y'], q['z'], q['w']]).apply([1.0, 0.0, 0.0])
        assert along == pytest.approx(force / np.linalg.norm(force), abs=1e-9)
    colours = [tuple(a['color'][k] for k in 'rgba') for a in forces['arrows']]
    limit = CELL.panel.internal_force_limit
    assert colours == [pytest.approx(force_colour(s, limit)) for s in sizes]


def test_the_colour_says_where_the_force_is_against_the_limit() -> None:
    assert force_colour(10.0, 500.0) == FORCE_COLOURS[0]
    assert force_colour(300.0, 500.0) == FORCE_COLOURS[1]
    assert force_colour(500.0, 500.0) == FORCE_COLOURS[2]


def test_the_transforms_put_each_base_and_the_panel_in_the_cell_frame() -> None:
    sent = as_dict(panel_transforms(_state().snapshot(), NOW))['transforms']
    tfs = {t['child_frame_id']: t for t in sent}
    assert set(tfs) == {names.PANEL_FRAME, *(base_frame(n) for n in NAMES)}
    assert all(t['parent_frame_id'] == names.CELL_FRAME for t in tfs.values())
    for name, base in zip(NAMES, bases(CELL), strict=True):
        t = tfs[base_frame(name)]['translation']
        assert [t['x'], t['y'], t['z']] == pytest.approx(base.p.tolist(), abs=1e-12)
    p = tfs[names.PANEL_FRAME]['translation']
    assert [p['x'], p['y'], p['z']] == pytest.approx(PANEL_P.tolist(), abs=1e-12)


def test_the_status_gives_the_forces_the_panel_age_and_every_positioner() -> None:
    doc = panel_status_document(_state().snapshot(), NOW)
    json.dumps(doc)  # JSON as sent
    assert doc['coordinator'] == {'level': 0, 'message': 'idle'}
    assert doc['panel_age_s'] == pytest.approx(0.2) and doc['panel_stale'] is False
    assert [a['name'] for a in doc['attachments']] == list(NAMES)
    assert doc['internal_force_n'] == pytest.approx(max(a['size_n'] for a in doc['attachments']))
    assert doc['internal_force_n'] > 100.0
    assert doc['internal_force_limit_n'] == CELL.panel.internal_force_limit
    for a in doc['attachments']:
        assert np.linalg.norm(a['force_n']) == pytest.approx(a['size_n'])
    assert doc['positioners'][0] == {'name': 'p1', 'positioner': {'level': 0,
                                                                  'message': 'settled'},
                                     'drives': {'level': 0, 'message': 'ok'}}
    assert doc['positioners'][1]['positioner'] is None and doc['waiting_for'] == []
    assert set(doc) <= set(panel_status_schema()['properties'])
    assert panel_status_document(_state().snapshot(), NOW + 5.0)['panel_stale'] is True


def test_what_has_not_come_is_left_out_and_said() -> None:
    empty = PanelWatchState().snapshot()
    assert _entities(panel_scene(empty, NOW, 1e-3)) == {}
    assert as_dict(panel_transforms(empty, NOW))['transforms'] == []
    doc = panel_status_document(empty, NOW)
    assert doc['internal_force_n'] is None and doc['panel_stale'] is True
    assert "the coordinator's parameters" in doc['waiting_for']
    assert "the panel's tracker" in doc['waiting_for']
    known = PanelWatchState()
    known.coordinator_settings(SETTINGS)
    snapshot = known.snapshot()
    assert set(_entities(panel_scene(snapshot, NOW, 1e-3))) == {'bases'}
    doc = panel_status_document(snapshot, NOW)
    assert doc['forces_waiting'] == 'no load cells heard of p1, p2, p3'
    assert doc['waiting_for'] == ["the panel's tracker", 'p1 load cells', 'p2 load cells',
                                  'p3 load cells']
