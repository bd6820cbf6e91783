"""From a calibration run's data to the calibration file: identify the machine
(:mod:`positioning_cell.calibration.identify`), validate it on the hold-out poses, write
``calibration.yaml`` and ``calibration_report.md`` (with plots) into a folder, with a few
lines for the person running it. The same for the live run and for a bag."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import observability as obs
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.calibrated import Nominal
from positioning_cell.calibration.collect import Collected
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.envelope import envelope_of
from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.calibration.report import predict, write_report


class Figures(NamedTuple):
    """An identification in numbers: the fit poses' position residual RMS under the calibrated
    model (m), measured vs predicted at the hold-out poses (RMS, m; NaN without hold-out
    poses), and how many of how many parameters were identified."""

    fit_rms: float
    hold_out_rms: float
    identified: int
    parameters: int


class Written(NamedTuple):
    """A calibration written: the file, the report, the figures, a sentence."""

    path: Path
    report: Path
    figures: Figures
    summary: str


def rms(a: Any) -> float:
    """RMS of the norms of the rows of ``a`` (N, k) (NaN when empty)."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(a)**2, axis=1)))) if len(a) else float('nan')


def identify_and_write(settings: Nominal, collected: Collected, out: Path,
                       program: dict[str, Any], say: Callable[[str], None]) -> Written:
    """Identify the machine of ``settings`` (its nominal mechanism, payload, structure) from
    ``collected``, validate it on its hold-out poses, write the file (``program``: how the
    data were taken, kept in it) and the report into ``out`` (IdentificationError, nothing
    written, when the data cannot identify the machine)."""
    s = settings
    for marker, why in collected.skipped:
        say(f'left out pose {marker.pose} ({marker.set}): {why}')
    result = idf.identify(s.mechanism, s.payload, s.structure, collected.fit)
    model = result.model(s.mechanism, s.payload, s.structure)
    fit = predict(s.mechanism, model, collected.fit)
    hold = predict(s.mechanism, model, collected.hold_out) if len(collected.hold_out.joints) \
        else None
    hold_doc = None
    hold_verdict = None
    if hold is not None:
        hold_verdict = idf.hold_out_adequacy(result, s.mechanism, s.payload, s.structure,
                                             collected.hold_out)
        promised = idf.pose_uncertainty(result.x, result.covariance, s.mechanism, s.payload,
                                        s.structure, *collected.hold_out_commanded,
                                        model_error=result.model_error)
        sigma_p = np.sqrt(np.trace(promised[:, :3, :3], axis1=1, axis2=2))
        hold_doc = {'poses': len(collected.hold_out.joints),
                    'promised_sigma_um': round(float(np.sqrt(np.mean(sigma_p**2))) * 1e6, 3),
                    'nominal_rms_um': round(rms(hold.nominal[0]) * 1e6, 3),
                    'calibrated_rms_um': round(rms(hold.calibrated[0]) * 1e6, 3),
                    'calibrated_max_um': round(float(np.linalg.norm(hold.calibrated[0], axis=1)
                                                     .max()) * 1e6, 3)}
    ident = result.identifiability
    indices = measured_indices(settings, collected.fit, ident.identified)
    production = production_sigma(settings, result, str(program.get('production', '')))
    out.mkdir(parents=True, exist_ok=True)
    verdicts = [v for v in (result.adequacy, hold_verdict) if v is not None]
    envelope = envelope_of(s.mechanism, collected.fit.position, collected.fit.quaternion,
                           s.payload.mass, collected.fit.temperature)
    extra = {'adequacy': {v.label: v.to_document() for v in verdicts},
             'envelope': envelope.to_document()}
    doc = calfile.document(result, s.mechanism, idf.IdentificationSettings().seating_force,
                           program, hold_doc, extra=extra)
    path = calfile.write(out / 'calibration.yaml', doc)
    report = write_report(out, result, fit, hold, indices=indices, production=[production],
                          verdicts=[v.verdict() for v in verdicts])
    say(f'identified {ident.rank}/{len(ident.identified)} parameters from '
        f'{len(collected.fit.joints)} poses (chi2/dof {result.chi2 / result.dof:.2f}); fit '
        f'residual RMS {rms(fit.calibrated[0]) * 1e6:.2f} um (nominal model '
        f'{rms(fit.nominal[0]) * 1e6:.1f} um)')
    if hold_doc is not None:
        say(f'hold-out ({hold_doc["poses"]} poses): measured vs predicted RMS '
            f'{hold_doc["calibrated_rms_um"]} um, max {hold_doc["calibrated_max_um"]} um '
            f'(nominal model {hold_doc["nominal_rms_um"]} um); the calibrated model\'s own '
            f'uncertainty there: {hold_doc["promised_sigma_um"]} um (1 sigma, |dp|)')
    for verdict in verdicts:
        say(verdict.verdict())
    if ident.merged:
        say('fixed (not separable or not excited): ' + ', '.join(ident.merged))
    known = indices['identified']
    say(f'observability of the identified parameters: smallest singular value '
        f'{known.sigma_min:.3g}, condition {known.condition:.3g}, O1 {known.o1:.3g}; '
        f'{production}')
    say(f'calibration: {path}\nreport:      {report}')
    figures = Figures(rms(fit.calibrated[0]),
                      rms(hold.calibrated[0]) if hold is not None else float('nan'),
                      ident.rank, len(ident.identified))
    return Written(path, report, figures,
                   f'identified {ident.rank}/{len(ident.identified)} parameters from '
                   f'{len(collected.fit.joints)} poses, written to {path}')


def measured_indices(settings: Nominal, data: idf.CalibrationData,
                     identified: np.ndarray) -> dict[str, obs.Indices]:
    """The observability indices of the measured fit poses' scaled whitened Jacobian, under
    the conditions they were measured in: of all the parameters and of the ``identified``
    (mask) ones."""
    s = settings
    rows = idf.information_rows(s.mechanism, s.payload, s.structure, data.position,
                                data.quaternion, data.covariance, data.joint_sigma,
                                conditions=Conditions(data.temperature, data.approach),
                                reference=idf.reference_temperature(data))
    return {'all parameters': obs.observability(rows),
            'identified': obs.observability(rows[:, :, identified])}


def production_sigma(settings: Nominal, result: idf.Identification, production: str) -> str:
    """A sentence: the calibrated model's own predicted pose σ (RMS and largest, position and
    angle) at the production poses of the program file ``production`` (empty: the shipped
    one; :func:`positioning_cell.calibration.program.production_poses`)."""
    s = settings
    p, q = prog.production_poses(s.mechanism, ProgramSettings(production=production))
    cov = idf.pose_uncertainty(result.x, result.covariance, s.mechanism, s.payload,
                               s.structure, p, q)
    sigma_p = np.sqrt(np.trace(cov[:, :3, :3], axis1=1, axis2=2))
    sigma_r = np.sqrt(np.trace(cov[:, 3:, 3:], axis1=1, axis2=2))
    return (f'predicted at the {len(p)} production poses: position sigma RMS '
            f'{np.sqrt(np.mean(sigma_p**2)) * 1e6:.2f} um (max {sigma_p.max() * 1e6:.2f} um), '
            f'angle sigma RMS {np.sqrt(np.mean(sigma_r**2)) * 1e6:.1f} urad')


def fit_so_far(settings: Nominal, collected: Collected) -> str:
    """'; fit so far ...': the residual of an identification on the fit poses measured so far
    (a progress line's tail)."""
    s, data = settings, collected.fit
    try:
        result = idf.identify(s.mechanism, s.payload, s.structure, data)
    except idf.IdentificationError as err:
        return f'; fit so far: not yet ({str(err).split(";")[0]})'
    return (f'; fit so far ({len(data.joints)} poses, {result.identifiability.rank} '
            f'parameters): residual RMS {rms(result.pose_residual_position[:, None]) * 1e6:.2f}'
            ' um')
