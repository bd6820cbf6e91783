"""The positioner's calibrated machine: the identified model its ``calibration_file``
parameter names, built for its payload (:mod:`positioning_cell.calibration.file`); and the
positioner's machine as the tools read it from a parameter file."""

from __future__ import annotations

from pathlib import Path

from positioning_cell import files
from positioning_cell.calibration.file import CalibrationFileError, load
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.names import NODE_POSITIONER
from positioning_cell.parameters import parse

#: The positioner parameter that names the calibration file.
CALIBRATION_FILE = 'compensation.calibration_file'


#: Longest time the positioner waits for a calibration file to load (s): a real one loads in
#: some 20 ms, the largest accepted (256 KiB) in some 0.2 s; the bound keeps the node's
#: parameter services and its stop answering whatever the file system does.
LOAD_TIMEOUT_S = 1.0


def calibrated_machine(settings: PositionerSettings,
                       timeout: float = LOAD_TIMEOUT_S) -> MachineModel | None:
    """The machine identified in ``settings``' calibration file, carrying its payload (None:
    no file set), loaded in a worker thread within ``timeout`` s
    (:func:`positioning_cell.files.within`). CalibrationFileError (a ConfigError) when the
    file cannot be used or does not load in time."""
    path = settings.compensation.calibration_file
    if not path:
        return None

    def build() -> MachineModel:
        return load(path, settings.mechanism).model(settings.mechanism, settings.payload,
                                                    settings.structure)

    return files.within(timeout, build, files.describe(files.CALIBRATION_FILE, path),
                        CalibrationFileError)


def machine_settings(config: str | Path) -> PositionerSettings:
    """The positioner's settings in a parameter file without its compensation block: the
    nominal machine, payload, structure and motion a tool needs to calibrate it or predict its
    accuracy (a compensation block naming a calibration file is not loaded)."""
    params = node_parameters(load_parameter_file(config), NODE_POSITIONER)
    params.pop('compensation', None)
    return parse(PositionerSettings, params)
