"""The watch window's table as text (the terminal watch draws it with rich; a test reads it
back): one row per axis with the commanded and measured value, the deviation, the tolerance,
an in/out marker and the measurement's standard uncertainty, then |Δp| and |Δθ| with their
in/out marker as measured, coloured by their decision by the monitor's rule (conforms: green,
indeterminate: yellow, does not conform: red; :attr:`Row.level`), and their expanded
uncertainty U (k = 2). It fits 80 columns. Positions: values in mm, deviations in µm;
rotations in degrees."""

from __future__ import annotations

import math
from dataclasses import dataclass

from positioning_cell.accuracy.decisions import Decision
from positioning_cell.accuracy.verdicts import DECISION_LEVELS
from positioning_cell.frames.transforms import MM_PER_M
from positioning_cell.watch.deviation import AXES, Deviation

#: The in/out markers (plain ASCII: they survive any terminal, SSH and tmux).
IN, OUT = 'IN', 'OUT'
#: Column headers of :func:`rows` (the |Δp|, |Δθ| rows give U, k = 2, in the last).
HEADERS = ('axis', 'commanded', 'measured', 'deviation', 'tolerance', '', 'u (k=1)/U')
#: Each decision in words (the pose line).
DECISION_MARKERS = {Decision.CONFORMS: 'CONFORMS', Decision.INDETERMINATE: 'INDETERMINATE',
                    Decision.DOES_NOT_CONFORM: 'DOES NOT CONFORM'}
UM_PER_M = 1e6


@dataclass(frozen=True)
class Row:
    """One line of the table, every cell already text; ``ok`` drives the colour."""

    axis: str
    commanded: str
    measured: str
    deviation: str
    tolerance: str
    marker: str
    uncertainty: str
    ok: bool
    #: 'ok', 'warn' or 'error' (an axis: ok or error; |Δp|, |Δθ|: their decision's level).
    level: str = 'ok'

    def cells(self) -> tuple[str, ...]:
        """The cells in :data:`HEADERS` order."""
        return (self.axis, self.commanded, self.measured, self.deviation, self.tolerance,
                self.marker, self.uncertainty)


def _marker(ok: bool) -> str:
    return IN if ok else OUT


def rows(dev: Deviation) -> list[Row]:
    """The table of ``dev``: six axis rows, then |Δp| and |Δθ|."""
    out = []
    ok = dev.axis_ok
    for i, axis in enumerate(AXES):
        if i < 3:
            value = (f'{dev.commanded[i] * MM_PER_M:.4f} mm',
                     f'{dev.measured[i] * MM_PER_M:.4f} mm',
                     f'{dev.deviation[i] * UM_PER_M:+.1f} µm',
                     f'±{dev.axis_tolerance[i] * UM_PER_M:.1f} µm',
                     f'{dev.uncertainty[i] * UM_PER_M:.1f} µm')
        else:
            value = (f'{math.degrees(dev.commanded[i]):.5f}°',
                     f'{math.degrees(dev.measured[i]):.5f}°',
                     f'{math.degrees(dev.deviation[i]):+.5f}°',
                     f'±{math.degrees(dev.axis_tolerance[i]):.5f}°',
                     f'{math.degrees(dev.uncertainty[i]):.5f}°')
        out.append(Row(axis, value[0], value[1], value[2], value[3], _marker(bool(ok[i])),
                       value[4], bool(ok[i]), 'ok' if ok[i] else 'error'))
    verdict = dev.verdict
    position, orientation = verdict.position_decision, verdict.orientation_decision
    out.append(Row('|Δp|', '', '', f'{dev.position_error * UM_PER_M:.1f} µm',
                   f'≤{dev.tolerances.position * UM_PER_M:.1f} µm',
                   _marker(verdict.position_ok),
                   f'U {verdict.position_uncertainty * UM_PER_M:.1f} µm',
                   position is Decision.CONFORMS, DECISION_LEVELS[position]))
    out.append(Row('|Δθ|', '', '', f'{math.degrees(dev.orientation_error):.5f}°',
                   f'≤{math.degrees(dev.tolerances.orientation):.5f}°',
                   _marker(verdict.orientation_ok),
                   f'U {math.degrees(verdict.orientation_uncertainty):.4f}°',
                   orientation is Decision.CONFORMS, DECISION_LEVELS[orientation]))
    return out
