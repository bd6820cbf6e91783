"""A calibration file that identifies a machine exactly (every parameter, a tiny sigma): what
a perfect calibration of a simulated machine would write, for the procedures' in-process
tests (the cell's own calibration is judged in test_calibration and test_run_cell)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.identify import Identifiability, Identification
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.core.mechanism import Mechanism


def exact_calibration(machine: MachineModel, nominal: Mechanism, path: Path) -> Path:
    """``machine`` over ``nominal`` as a calibration file at ``path``."""
    exact = Identification(cp.vector_of(machine, nominal), np.eye(cp.COUNT) * 1e-18,
                           Identifiability(np.ones(cp.COUNT, bool), np.ones(cp.COUNT), {},
                                           np.ones(cp.COUNT)),
                           np.zeros((1, 6)), np.zeros(1), 0.0, 1, 0)
    return calfile.write(path, calfile.document(exact, nominal, 1.0, {'test': 'exact'}))
