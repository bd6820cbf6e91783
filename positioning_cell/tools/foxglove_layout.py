"""``python -m positioning_cell.tools.foxglove_layout [--panel] [PATH]``: write the Foxglove
layout of the live view (config/foxglove_layout.json by default) with foxglove-sdk's layout
types: the 3-D panel on /live/scene and /live/transforms (base fixed), the deviation plots (x,
y, z in µm; rx, ry, rz and |Δθ| in degrees; |Δp| in µm) and a table of /live/deviation and
/live/status. ``--panel``: the panel view's (``view: panel``; config/foxglove_panel_layout.json):
the 3-D panel following the ``cell`` frame, the largest internal force and its limit over time,
and a table of the status. test_foxglove_layout.py checks the shipped files are what this
writes."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import foxglove.layouts as fl

from positioning_cell import names
from positioning_cell.config import share_directory
from positioning_cell.tools.exits import Exit
from positioning_cell.watch.deviation import AXES

#: The shipped layouts: the positioner's and the panel's.
LAYOUT_FILE = 'foxglove_layout.json'
PANEL_LAYOUT_FILE = 'foxglove_panel_layout.json'


def _plot(title: str, series: Sequence[tuple[str, str]]) -> fl.PlotPanel:
    return fl.PlotPanel(title=title, config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f'{names.LIVE_DEVIATION}.{field}', label=label,
                             enabled=True) for field, label in series],
        show_legend=True))


def layout() -> fl.Layout:
    """The live view's layout (module docstring)."""
    scene = fl.ThreeDeePanel(title='positioner', config=fl.ThreeDeeConfig(
        follow_tf=names.BASE_FRAME,
        topics={names.LIVE_SCENE: fl.BaseRendererSceneUpdateTopicSettings(visible=True)}))
    positions = _plot('position deviation, µm', [(f'{a}_um', a) for a in AXES[:3]]
                      + [('position_error_um', '|Δp|')])
    angles = _plot('orientation deviation, deg', [(f'{a}_deg', a) for a in AXES[3:]]
                   + [('orientation_error_deg', '|Δθ|')])
    tables = fl.SplitContainer(direction='column', items=[
        fl.SplitItem(content=fl.TablePanel(title='deviation', config=fl.TableConfig(
            topic_path=names.LIVE_DEVIATION))),
        fl.SplitItem(content=fl.TablePanel(title='status', config=fl.TableConfig(
            topic_path=names.LIVE_STATUS)))])
    plots = fl.SplitContainer(direction='column', items=[
        fl.SplitItem(content=positions), fl.SplitItem(content=angles)])
    return fl.Layout(content=fl.SplitContainer(direction='row', items=[
        fl.SplitItem(proportion=2, content=scene), fl.SplitItem(proportion=2, content=plots),
        fl.SplitItem(proportion=1, content=tables)]))


def panel_layout() -> fl.Layout:
    """The panel view's layout (module docstring)."""
    scene = fl.ThreeDeePanel(title='coordinated cell', config=fl.ThreeDeeConfig(
        follow_tf=names.CELL_FRAME,
        topics={names.LIVE_SCENE: fl.BaseRendererSceneUpdateTopicSettings(visible=True)}))
    forces = fl.PlotPanel(title='internal force, N (load cells)', config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f'{names.LIVE_STATUS}.{field}', label=label, enabled=True)
               for field, label in (('internal_force_n', 'largest'),
                                    ('internal_force_limit_n', 'limit'))],
        show_legend=True))
    status = fl.TablePanel(title='status', config=fl.TableConfig(topic_path=names.LIVE_STATUS))
    return fl.Layout(content=fl.SplitContainer(direction='row', items=[
        fl.SplitItem(proportion=2, content=scene), fl.SplitItem(proportion=1, content=fl.
                                                                SplitContainer(
            direction='column', items=[fl.SplitItem(content=forces),
                                       fl.SplitItem(content=status)]))]))


def layout_text(panel: bool = False) -> str:
    """The layout (``panel``: the panel view's) as the shipped file holds it (indented JSON,
    one newline at the end)."""
    made = panel_layout() if panel else layout()
    return json.dumps(json.loads(made.to_json()), indent=2, ensure_ascii=False) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """Write the layout (module docstring)."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').split('\n\n')[0])
    parser.add_argument('--panel', action='store_true',
                        help="the panel view's layout (view: panel) instead")
    parser.add_argument('path', nargs='?', type=Path,
                        help=f'where to write it (default: config/{LAYOUT_FILE}, or '
                        f'config/{PANEL_LAYOUT_FILE} with --panel)')
    args = parser.parse_args(argv)
    path = args.path or share_directory() / 'config' / (PANEL_LAYOUT_FILE if args.panel
                                                         else LAYOUT_FILE)
    path.write_text(layout_text(args.panel), encoding='utf-8')
    print(path)
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
