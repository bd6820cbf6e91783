"""``cell watch --panel``: the coordinated cell's watch window (rich; issue 27 item 6): the
coordinator's state and last outcome, the panel as its tracker measures it (cell frame: position
in mm, rotation vector in mrad), the largest internal force at one attachment as the legs' load
cells give it (:mod:`positioning_cell.watch.panel`), and a row per positioner of the cell file:
its state and its drives'. Redrawn as ``cell watch`` is (:func:`~.cell_watch.run_window`);
read-only."""

from __future__ import annotations

import time

import numpy as np
from rich.console import Group
from rich.table import Table
from rich.text import Text

from positioning_cell import names
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.tools.cell_watch import drives_text, status_text
from positioning_cell.watch.panel import PanelSnapshot
from positioning_cell.watch.state import is_stale

#: The table's columns.
HEADERS = ('positioner', 'state', 'drives', 'message')


def panel_line(snapshot: PanelSnapshot, now: float) -> Text:
    """The panel's measured pose in the cell frame and its age, or what it waits for."""
    line = Text('panel (cell frame): ', style='bold')
    if snapshot.panel is None:
        return line.append(f'waiting for {names.PANEL_MEASURED_POSE}', style='dim')
    p, q = snapshot.panel
    r = scipy_rotation().from_quat(q).as_rotvec()
    age = now - snapshot.panel_stamp
    stale = is_stale(age)
    return line.append('x y z ' + ' '.join(f'{v:+.4f}' for v in np.asarray(p) * 1e3)
                       + ' mm  rx ry rz ' + ' '.join(f'{v:+.3f}' for v in r * 1e3) + ' mrad  ',
                       ).append(f'measured {age:.2f} s ago' + (' (STALE)' if stale else ''),
                                style='yellow' if stale else 'dim')


def force_line(snapshot: PanelSnapshot) -> Text:
    """The largest internal force at one attachment by the load cells, or why none."""
    line = Text('internal force (load cells, at rest): ', style='bold')
    force = snapshot.internal_force()
    if isinstance(force, str):
        return line.append(force, style='dim')
    return line.append(f'{force:.0f} N at most at one attachment')


def render_panel(snapshot: PanelSnapshot, now: float) -> Group:
    """The panel's watch window of ``snapshot`` at wall time ``now`` (s)."""
    title = Text.assemble(('cell watch: the panel', 'bold'), '  ',
                          time.strftime('%H:%M:%S', time.localtime(now)))
    coordinator = status_text('coordinator', snapshot.coordinator, 'no status yet')
    last = {} if snapshot.coordinator is None else snapshot.coordinator.values
    parts: list[Text | Table] = [title, coordinator]
    if last.get('last_reason'):
        parts.append(Text(f'  last: {last.get("last_code", "")}: {last["last_reason"]}',
                          style='dim'))
    parts += [panel_line(snapshot, now), force_line(snapshot)]
    if not snapshot.names:
        parts.append(Text(f'waiting for /{names.NODE_COORDINATOR} cell_file', style='yellow'))
    else:
        table = Table(*HEADERS, title_justify='left', expand=False)
        for name in snapshot.names:
            pos, drv = snapshot.positioners.get(name), snapshot.drives.get(name)
            state = '?' if pos is None else pos.values.get('state', pos.message)
            table.add_row(name, state, drives_text(drv), '' if pos is None else pos.message)
        parts.append(table)
    parts.append(Text('q or Ctrl-C quits', style='dim'))
    return Group(*parts)


__all__ = ['HEADERS', 'force_line', 'panel_line', 'render_panel']
