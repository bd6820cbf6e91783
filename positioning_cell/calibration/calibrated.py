"""The positioner's calibrated machine: the identified model its ``calibration_file``
parameter names, built for its payload (:mod:`positioning_cell.calibration.file`), loaded within
a bounded time."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from positioning_cell import files
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.envelope import Envelope
from positioning_cell.calibration.file import Calibration, CalibrationFileError, parse, read
from positioning_cell.calibration.identify import pose_uncertainty
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.mechanics.statics import Payload, Structure

FloatArray = NDArray[np.float64]

#: Longest time the positioner waits for a calibration file to be read (s): the bound keeps the
#: node's parameter services and its stop answering whatever the file system does. Only the
#: read is bounded: a real file parses and builds in some 15 to 40 ms, the largest accepted
#: (384 KiB) in some 0.25 s, and a loaded machine stretched that past 1 s in CI (a good file
#: refused), whereas CPU work ends on its own.
LOAD_TIMEOUT_S = 1.0


class Nominal(Protocol):
    """The nominal machine a calibration starts from (the positioner's settings have it)."""

    @property
    def mechanism(self) -> Mechanism: ...

    @property
    def payload(self) -> Payload: ...

    @property
    def structure(self) -> Structure: ...


class _Compensation(Protocol):
    @property
    def calibration_file(self) -> str: ...


class CalibratedSettings(Nominal, Protocol):
    """What a calibrated machine is built from: the calibration file of the compensation
    settings and the nominal machine (:class:`Nominal`;
    the positioner's settings, :class:`positioning_cell.motion.settings.PositionerSettings`,
    are one)."""

    @property
    def compensation(self) -> _Compensation: ...


class Calibrated(NamedTuple):
    """A loaded calibration as the positioner uses it: the identified ``model`` built for the
    payload, the validity ``envelope`` it was identified over (None: the file has none), what
    an older file ``lacks``, and the loaded ``calibration`` over the ``nominal`` mechanism
    (None: not known; then no uncertainty is stated)."""

    model: MachineModel
    envelope: Envelope | None
    lacks: tuple[str, ...]
    calibration: Calibration | None = None
    nominal: Mechanism | None = None

    def pose_covariance(self, position: FloatArray, quaternion: FloatArray,
                        conditions: Conditions, temperature_sigma: float) -> FloatArray | None:
        """Covariance (6, 6) (m², rad²) of where this machine puts the platform when
        commanded to the pose (3,) m, (4,) under ``conditions`` whose temperature has the
        standard uncertainty ``temperature_sigma`` K: the file's parameter covariance and
        model error, and the temperature's
        (:func:`positioning_cell.calibration.identify.pose_uncertainty`). None without the
        file's data."""
        cal, model = self.calibration, self.model
        if cal is None or self.nominal is None or model.payload is None \
                or model.structure is None:
            return None
        cov: FloatArray = pose_uncertainty(
            cal.x, cal.covariance, self.nominal, model.payload, model.structure,
            position[None], quaternion[None], cal.seating_force, cal.model_error,
            conditions=conditions, reference_temperature=cal.reference_temperature,
            temperature_sigma=temperature_sigma)[0]
        return cov


def calibrated_machine(settings: CalibratedSettings,
                       timeout: float = LOAD_TIMEOUT_S) -> Calibrated | None:
    """The machine identified in ``settings``' calibration file, carrying its payload (None:
    no file set). The file is read in a worker thread within ``timeout`` s
    (:func:`positioning_cell.files.within`), then parsed and built here: the bound is on the
    file system, not on a busy processor (a file of the largest size parses in bounded time,
    and stops at its next node once the process stops). CalibrationFileError (a ConfigError)
    when the file cannot be used or is not read in time."""
    path = settings.compensation.calibration_file
    if not path:
        return None
    text = files.within(timeout, lambda: read(path), files.describe(files.CALIBRATION_FILE, path),
                        CalibrationFileError)
    calibration = parse(text, path, settings.mechanism)
    # The envelope's test of every move (Envelope.reasons) takes scipy.spatial's convex hull:
    # imported with the calibration, while it loads, not in the first move's callback (an
    # import there pauses that callback's executor thread for 0.2 s or more; the positioner
    # imports no scipy otherwise, positioning_cell.ros.spin).
    import scipy.spatial  # noqa: F401
    return Calibrated(calibration.model(settings.mechanism, settings.payload,
                                        settings.structure),
                      calibration.envelope, calibration.lacks, calibration, settings.mechanism)
