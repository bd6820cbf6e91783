"""The positioner's calibrated machine: the identified model its ``calibration_file``
parameter names, built for its payload (:mod:`positioning_cell.calibration.file`); and the
positioner's machine as the tools read it from a parameter file."""

from __future__ import annotations

from pathlib import Path

from positioning_cell.calibration.file import load
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.names import NODE_POSITIONER
from positioning_cell.parameters import parse

#: The positioner parameter that names the calibration file.
CALIBRATION_FILE = 'compensation.calibration_file'


def calibrated_machine(settings: PositionerSettings) -> MachineModel | None:
    """The machine identified in ``settings``' calibration file, carrying its payload (None:
    no file set). CalibrationFileError (a ConfigError) when the file cannot be used."""
    path = settings.compensation.calibration_file
    if not path:
        return None
    return load(path, settings.mechanism).model(settings.mechanism, settings.payload,
                                                settings.structure)


def machine_settings(config: str | Path) -> PositionerSettings:
    """The positioner's settings in a parameter file without its compensation block: the
    nominal machine, payload, structure and motion a tool needs to calibrate it or predict its
    accuracy (a compensation block naming a calibration file is not loaded)."""
    params = node_parameters(load_parameter_file(config), NODE_POSITIONER)
    params.pop('compensation', None)
    return parse(PositionerSettings, params)
