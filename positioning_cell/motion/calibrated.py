"""The positioner's calibrated machine: the identified model its ``calibration_file``
parameter names, built for its payload (:mod:`positioning_cell.calibration.file`)."""

from __future__ import annotations

from positioning_cell.calibration.file import load
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.motion.settings import PositionerSettings

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
