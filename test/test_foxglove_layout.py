"""config/foxglove_layout.json is what positioning_cell.tools.foxglove_layout writes (made with
foxglove-sdk's layout types, not by hand), and every message path it plots or tabulates is a
field the live view sends."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from workspace import MECH

from positioning_cell import names
from positioning_cell.accuracy.verdicts import Tolerances
from positioning_cell.config import config_path
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.nodes.live_view_messages import deviation_document
from positioning_cell.tools.foxglove_layout import LAYOUT_FILE, layout_text
from positioning_cell.watch.deviation import deviation


def _panels(node: Any) -> list[dict[str, Any]]:
    if node.get('type') == 'panel':
        return [node]
    return [p for item in node.get('items', []) for p in _panels(item['content'])]


def test_the_shipped_layout_is_the_generated_one() -> None:
    shipped = config_path(LAYOUT_FILE).read_text(encoding='utf-8')
    assert shipped == layout_text(), 'regenerate: python -m positioning_cell.tools.foxglove_layout'


def test_every_path_of_the_layout_is_sent() -> None:
    panels = _panels(json.loads(layout_text())['content'])
    kinds = {p['panelType'] for p in panels}
    assert {'ThreeDee', 'Plot', 'Table'} <= kinds
    home = (MECH.home_position, np.array([0.0, 0.0, 0.0, 1.0]))
    doc = deviation_document(deviation(home, home, np.eye(6) * 1e-12, 'base',
                                       CoordinateSystems(), MECH, Tolerances()), 0.0)
    plotted = [s['value'] for p in panels if p['panelType'] == 'Plot'
               for s in p['config']['paths']]
    assert len(plotted) == 8
    for path in plotted:
        topic, field = path.rsplit('.', 1)
        assert topic == names.LIVE_DEVIATION and field in doc, path
    tables = {p['config']['topicPath'] for p in panels if p['panelType'] == 'Table'}
    assert tables == {names.LIVE_DEVIATION, names.LIVE_STATUS}
    scene = next(p for p in panels if p['panelType'] == 'ThreeDee')
    assert set(scene['config']['topics']) == {names.LIVE_SCENE}
    assert scene['config']['followTf'] == names.BASE_FRAME


def test_the_shipped_panel_layout_is_the_generated_one_and_plots_what_is_sent() -> None:
    """config/foxglove_panel_layout.json (the panel view's): generated; its 3-D panel follows
    the cell frame, and its plots and table read fields of the panel view's status."""
    from test_live_view_panel import _state

    from positioning_cell.nodes.live_view_panel import panel_status_document
    from positioning_cell.tools.foxglove_layout import PANEL_LAYOUT_FILE

    shipped = config_path(PANEL_LAYOUT_FILE).read_text(encoding='utf-8')
    assert shipped == layout_text(panel=True), \
        'regenerate: python -m positioning_cell.tools.foxglove_layout --panel'
    panels = _panels(json.loads(shipped)['content'])
    scene = next(p for p in panels if p['panelType'] == 'ThreeDee')
    assert scene['config']['followTf'] == names.CELL_FRAME
    doc = panel_status_document(_state().snapshot(), 0.0)
    plotted = [s['value'] for p in panels if p['panelType'] == 'Plot'
               for s in p['config']['paths']]
    assert plotted
    for path in plotted:
        topic, field = path.rsplit('.', 1)
        assert topic == names.LIVE_STATUS and doc[field] is not None, path
    assert {p['config']['topicPath'] for p in panels if p['panelType'] == 'Table'} == {
        names.LIVE_STATUS}
