"""Judging only: the simulator's truth, read from the cell's parameter file (the simulator's
``pose_measurement`` section, ``truth.*``), never from the running cell. A procedure measures
with what the cell gives it; these functions only say, after the fact, how close that came to
the truth of a simulated machine (on a real cell the parameter file has no simulator section
and nothing is judged)."""

from __future__ import annotations

from pathlib import Path

from positioning_cell import names
from positioning_cell.calibration import file as calfile
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.parameters import parse
from positioning_cell.sim.campaign import truth_table
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.sim.truth import Truth


def simulator(config: Path) -> PoseMeasurementSettings | None:
    """The simulator's settings in the parameter file ``config`` (None without a simulator
    section: a real cell). ConfigError naming a bad key."""
    params = node_parameters(load_parameter_file(config), names.NODE_MEASUREMENT)
    return parse(PoseMeasurementSettings, params) if params else None


def simulation_truth(config: Path) -> Truth | None:
    """The simulator's true machine in ``config`` (None without a simulator section)."""
    sim = simulator(config)
    return None if sim is None else sim.true_machine()


def judge_calibration(path: Path, config: Path) -> tuple[Path, str] | None:
    """The calibration file ``path`` against the simulator's truth of ``config``: its truth
    table (each identified parameter against the truth, in its standard uncertainties) written
    to ``truth.md`` beside it; (that file, the table's summary line). None without a
    simulator section."""
    sim = simulator(config)
    if sim is None:
        return None
    nominal = sim.mechanism
    lines = truth_table(calfile.load(path, nominal), sim.true_machine(), nominal)
    table = path.with_name('truth.md')
    table.write_text('# Calibration against the simulation truth\n\n' + '\n'.join(lines) + '\n')
    return table, lines[-1].split(' (')[0]
