"""Effects of the simulated machine outside the model the cell identifies (issue 23): drive
errors (:mod:`.drive_errors`), temperature (:mod:`.thermal`) and compliance
(:mod:`.compliance`), and the state history they need (:mod:`.history`). Only the simulators
read them: they belong to the truth (:mod:`positioning_cell.sim.truth`)."""

from __future__ import annotations

from positioning_cell.parameters import ParameterError


def check_ordered(name: str, value: tuple[float, float]) -> None:
    """ParameterError naming ``name`` unless ``value`` is a range [low, high], low <= high."""
    if value[0] > value[1]:
        raise ParameterError(name, value, 'must be [low, high] with low <= high')
