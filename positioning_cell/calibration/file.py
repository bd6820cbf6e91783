"""``calibration.yaml``: an identified machine as the positioner loads it.

One YAML mapping under ``calibration:``: ``format`` (2), ``mechanism_fingerprint`` (of the
nominal mechanism it was identified over: a file of another machine is refused), ``date``
(ISO 8601, UTC), ``program`` (how it was measured), ``parameters`` (every parameter of
:data:`positioning_cell.calibration.parameters.PARAMETER_NAMES`: ``value``, ``sigma`` (null
when fixed), ``unit``, ``identified``), ``fixed`` (each parameter the data could not separate,
with those that absorbed it), ``seating_force`` (N) and ``residuals`` (χ², degrees of freedom,
pose-space residual per pose in µm), ``covariance`` (COUNT × COUNT, the parameters'
covariance), ``reference_temperature`` (°C, of the thermal terms), ``excluded`` (parameters
left out before the fit, with why), ``model_error`` (the standard uncertainty of what the model
misses, per joint kind: ``length_m``, ``theta_rad``; 0 when the model was adequate),
``adequacy`` (the χ² test of the fit, :mod:`positioning_cell.calibration.adequacy`),
``envelope`` (the conditions it was identified over,
:mod:`positioning_cell.calibration.envelope`) and, when measured, ``hold_out``.

Format 1 (26 parameters: geometry, zero offsets, clearance; no terms beyond geometry, no
reference temperature, model error, adequacy or envelope) still loads: its model is the one it
was identified with (the new terms zero), and :attr:`Calibration.lacks` names what it lacks.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from positioning_cell import files
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.conditions import STANDARD_TEMPERATURE, TEMPERATURE_RANGE
from positioning_cell.calibration.envelope import Envelope
from positioning_cell.calibration.identify import Identification
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanics.statics import Payload, Structure

FloatArray = NDArray[np.float64]
FORMAT = 2
#: Parameters of each format this version reads (a prefix of PARAMETER_NAMES).
FORMAT_COUNTS = {1: cp.FORMAT1_COUNT, 2: cp.COUNT}
#: What a format-1 file lacks.
FORMAT1_LACKS = (*cp.TERM_CLASSES, 'reference_temperature', 'model_error', 'adequacy',
                 'envelope')
#: Entries of a format-2 file that may be missing (then named in ``lacks``; the reference
#: temperature then 20 °C, the model error 0).
OPTIONAL = ('reference_temperature', 'model_error', 'adequacy', 'envelope')
_GEOMETRY_KEYS = ('base_radius', 'platform_radius', 'home_length', 'base_offsets',
                  'platform_offsets')


class CalibrationFileError(ConfigError):
    """A calibration file that cannot be used: unreadable, malformed, or of another mechanism
    (the message says which and why)."""


def fingerprint(mech: Mechanism) -> str:
    """Fingerprint of a nominal mechanism's geometry (16 hex digits of SHA-256 of its
    geometric parameters): a calibration belongs to the machine it was identified on."""
    params = mech.to_params()
    geometry = {k: params[k] for k in _GEOMETRY_KEYS}
    text = json.dumps(geometry, sort_keys=True, default=lambda v: np.asarray(v).tolist())
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Calibration:
    """A loaded calibration: the vector ``x`` (COUNT,), its ``sigma`` (NaN: fixed), which
    parameters were ``identified``, the ``seating_force`` N, everything else of the file in
    ``meta``, the parameters' ``covariance`` (COUNT, COUNT), the ``reference_temperature`` °C
    of the thermal terms, the ``model_error`` (6,) per joint (m, rad), the file's ``format``,
    what it ``lacks`` (an older format's missing classes and entries; module docstring) and
    its validity ``envelope`` (None: not stored). The parameters a file lacks are 0, as in
    the model it was identified with."""

    x: FloatArray
    sigma: FloatArray
    identified: NDArray[np.bool_]
    seating_force: float = 1.0
    meta: dict[str, Any] = field(default_factory=dict)
    covariance: FloatArray = field(default_factory=lambda: np.zeros((cp.COUNT, cp.COUNT)))
    reference_temperature: float = STANDARD_TEMPERATURE
    model_error: FloatArray = field(default_factory=lambda: np.zeros(6))
    format: int = FORMAT
    lacks: tuple[str, ...] = ()
    envelope: Envelope | None = None

    def model(self, nominal: Mechanism, payload: Payload, structure: Structure) -> MachineModel:
        """The calibrated machine carrying ``payload``."""
        return cp.machine_model(self.x, nominal, payload, structure, self.seating_force,
                                self.reference_temperature)


def model_error_entry(model_error: FloatArray) -> dict[str, float]:
    """The file's ``model_error`` of a per-joint model error (6,) m, rad (one value per kind:
    the legs share one, the θ axes another)."""
    return {'length_m': float(model_error[0]), 'theta_rad': float(model_error[3])}


def document(result: Identification, nominal: Mechanism, seating_force: float,
             program: dict[str, Any], hold_out: dict[str, Any] | None = None,
             date: datetime.datetime | None = None,
             extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The file's content (module docstring) for an identification over ``nominal``;
    ``extra``: further entries (``adequacy``, ``envelope``)."""
    when = (date or datetime.datetime.now(datetime.UTC)).isoformat(timespec='seconds')
    sigma = result.sigma
    params = {
        name: {'value': float(result.x[k]),
               'sigma': None if math.isnan(sigma[k]) else float(sigma[k]),
               'unit': cp.UNITS[k], 'identified': bool(result.identifiability.identified[k])}
        for k, name in enumerate(cp.PARAMETER_NAMES)}
    fixed = {name: [f'{partner} ({coef:+.3f})' for partner, coef in partners]
             for name, partners in result.identifiability.merged.items()}
    body: dict[str, Any] = {
        'format': FORMAT, 'mechanism_fingerprint': fingerprint(nominal), 'date': when,
        'program': program, 'seating_force': float(seating_force), 'parameters': params,
        'fixed': fixed,
        # rows in PARAMETER_NAMES order, m / rad squared: the correlations carry the promise
        'covariance': [[float(v) for v in row] for row in result.covariance],
        'residuals': {'chi2': round(result.chi2, 3), 'dof': result.dof,
                      'pose_position_um': [round(float(v) * 1e6, 3)
                                           for v in result.pose_residual_position]},
        'reference_temperature': float(result.reference_temperature),
        'excluded': dict(result.excluded),
        'model_error': model_error_entry(result.model_error)}
    if hold_out is not None:
        body['hold_out'] = hold_out
    body.update(extra or {})
    return {'calibration': body}


def write(path: str | Path, content: dict[str, Any]) -> Path:
    """Write the document to ``path`` (through a temporary file: never half a file; its
    folder created when missing)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + '.part')
    tmp.write_text(yaml.safe_dump(content, sort_keys=False))
    tmp.replace(out)
    return out


def read(path: str | Path) -> str:
    """The text of the calibration file ``path`` (:func:`positioning_cell.files.read_text`:
    checked, at most :data:`~positioning_cell.files.CALIBRATION_FILE`'s size): the part of a
    load that waits on the file system. CalibrationFileError naming what is wrong otherwise."""
    text = files.read_text(path, files.CALIBRATION_FILE, CalibrationFileError)
    assert isinstance(text, str)  # (not missing_ok)
    return text


def parse(text: str, path: str | Path, nominal: Mechanism) -> Calibration:
    """The calibration in ``text``, read from ``path``, checked for the nominal machine
    ``nominal``: the part of a load that only computes. CalibrationFileError naming what is
    wrong otherwise (in a short message, its values quoted in excerpts)."""
    where = files.describe(files.CALIBRATION_FILE, path)
    data = files.parse_yaml(text, where, CalibrationFileError)
    with files.brief_errors():
        return _calibration(data, nominal, where)


def load(path: str | Path, nominal: Mechanism) -> Calibration:
    """Read and check a calibration file for the nominal machine ``nominal``
    (:func:`read`, then :func:`parse`)."""
    return parse(read(path), path, nominal)


def _number(value: Any, where: str, name: str, low: float = -math.inf,
            high: float = math.inf) -> float:
    """A finite number within [low, high] (CalibrationFileError naming ``name``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        raise CalibrationFileError(f'{where}: {name} = {files.excerpt(value)}: not a finite '
                                   f'number within {low:g} to {high:g}')
    return float(value)


def _calibration(data: Any, nominal: Mechanism, where: str) -> Calibration:
    """The calibration of a loaded document (:func:`load`)."""
    body = data.get('calibration') if isinstance(data, dict) else None
    if not isinstance(body, dict):
        raise CalibrationFileError(f'{where}: no "calibration:" mapping')
    version = body.get('format')
    if isinstance(version, bool) or version not in FORMAT_COUNTS:
        raise CalibrationFileError(f'{where}: format {files.excerpt(version)}, expected one '
                                   f'of {", ".join(map(str, FORMAT_COUNTS))}')
    count = FORMAT_COUNTS[version]
    names = cp.PARAMETER_NAMES[:count]
    mine = fingerprint(nominal)
    if body.get('mechanism_fingerprint') != mine:
        raise CalibrationFileError(
            f'{where}: belongs to mechanism {files.excerpt(body.get("mechanism_fingerprint"))},'
            f' this positioner is {mine!r} (identified on another machine or geometry)')
    params = body.get('parameters')
    if not isinstance(params, dict):
        raise CalibrationFileError(f'{where}: no "parameters:" mapping')
    missing = [n for n in names if n not in params]
    if missing:
        listed = ', '.join(missing[:4]) + (f' and {len(missing) - 4} more' if len(missing) > 4
                                           else '')
        raise CalibrationFileError(f'{where}: lacks parameters {listed}')
    x = np.zeros(cp.COUNT)
    sigma = np.full(cp.COUNT, np.nan)
    identified = np.zeros(cp.COUNT, dtype=bool)
    for k, name in enumerate(names):
        entry = params[name]
        value = entry.get('value') if isinstance(entry, dict) else None
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise CalibrationFileError(f'{where}: {name}.value = {files.excerpt(value)}: not a '
                                       'finite number')
        x[k] = value
        identified[k] = bool(entry.get('identified', False))
        spread = entry.get('sigma')
        if spread is not None:
            if isinstance(spread, bool) or not isinstance(spread, (int, float)) \
                    or not math.isfinite(spread) or spread < 0.0:
                raise CalibrationFileError(f'{where}: {name}.sigma = {files.excerpt(spread)}: '
                                           'not a finite number >= 0 (or null: fixed)')
            sigma[k] = spread
    if x[cp.R_A] < 0.0 or x[cp.R_B] < 0.0:
        raise CalibrationFileError(f'{where}: a clearance is negative')
    seating = body.get('seating_force', 1.0)
    if isinstance(seating, bool) or not isinstance(seating, (int, float)) or seating <= 0.0:
        raise CalibrationFileError(f'{where}: seating_force = {files.excerpt(seating)}: must '
                                   'be > 0 N')
    try:
        stored = np.asarray(body.get('covariance'), dtype=float)
    except (TypeError, ValueError):
        stored = np.empty(0)
    if stored.shape != (count, count) or not np.all(np.isfinite(stored)):
        raise CalibrationFileError(f'{where}: covariance must be {count} x {count} '
                                   'finite numbers')
    covariance = np.zeros((cp.COUNT, cp.COUNT))
    covariance[:count, :count] = stored
    reference, model_error = STANDARD_TEMPERATURE, np.zeros(6)
    if version == 1:
        lacks: tuple[str, ...] = FORMAT1_LACKS
    else:
        if 'reference_temperature' in body:
            reference = _number(body['reference_temperature'], where,
                                'reference_temperature', *TEMPERATURE_RANGE)
        if 'model_error' in body:
            error = body['model_error']
            if not isinstance(error, dict):
                raise CalibrationFileError(f'{where}: model_error is not a mapping')
            model_error = np.repeat([_number(error.get(key), where, f'model_error.{key}', 0.0)
                                     for key in ('length_m', 'theta_rad')], 3)
        lacks = tuple(key for key in OPTIONAL if key not in body)
    envelope = None
    if 'envelope' in body and version >= 2:
        try:
            envelope = Envelope.from_document(body['envelope'])
        except InputError as err:
            raise CalibrationFileError(f'{where}: {err}') from None
    meta = {k: v for k, v in body.items() if k not in ('parameters', 'covariance')}
    return Calibration(x, sigma, identified, float(seating), meta, covariance, reference,
                       model_error, int(version), lacks, envelope)
