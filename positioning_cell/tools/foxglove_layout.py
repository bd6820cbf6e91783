"""``python -m positioning_cell.tools.foxglove_layout [PATH]``: write the Foxglove layout of
the live view (config/foxglove_layout.json by default) with foxglove-sdk's layout types: the
3-D panel on /live/scene and /live/transforms (base fixed), the deviation plots (x, y, z in
µm; rx, ry, rz and |Δθ| in degrees; |Δp| in µm) and a table of /live/deviation and
/live/status. test_foxglove_layout.py checks the shipped file is what this writes."""

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

#: The shipped layout.
LAYOUT_FILE = 'foxglove_layout.json'


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


def layout_text() -> str:
    """The layout as the shipped file holds it (indented JSON, one newline at the end)."""
    return json.dumps(json.loads(layout().to_json()), indent=2, ensure_ascii=False) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """Write the layout (module docstring)."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').split('\n\n')[0])
    parser.add_argument('path', nargs='?', type=Path,
                        default=share_directory() / 'config' / LAYOUT_FILE,
                        help=f'where to write it (default: config/{LAYOUT_FILE})')
    args = parser.parse_args(argv)
    args.path.write_text(layout_text(), encoding='utf-8')
    print(args.path)
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
