"""Calibration of an unknown machine (issue 12), judged on the simulated truth with all its
effects outside the identified model on (drive lead, periodic and reversal errors; air drift,
leg heating, expansion and the air sensor's error; compliance of the legs, θ drives and U/S
joints): five seeded machines (truth.geometry_seed 0..4, the drives' and thermal seeds
likewise), each calibrated from a simulated program and judged on hold-out poses never fitted.

The calibration run (sim.campaign.measure_program, one pose every SECONDS_PER_MOVE s per
move so the air drifts and the legs warm): the program's 30 poses (calibration.program,
D-optimal) in two sessions ``SESSIONS`` h apart (alternate poses of the tour in each: the
thermal terms need a measured temperature range of at least 1 K, which a 15-minute run does
not give), each pose reached through an intermediate pose ``APPROACH`` m below it (even
poses) or above it (odd poses) along base z, so every axis is approached from both sides and
the reversal is excited (the program chooser approaches all from below). The hold-out poses
are visited likewise, at a time between the sessions.

Per machine, hold-out truth |Δp| RMS and max for: the nominal inverse kinematics
(uncompensated), the 26-parameter geometry-and-clearance fit (compliance, thermal, lead and
reversal not fitted), the calibrated model (commands under the measured air temperature and
the approach used, judged under the true conditions of those moves: air, heated legs,
approach) and the positioner's own mover in mode ``measured``; a change of payload (30, 70 kg
from 50; the model told the mass) and of the air (+5, −5 K; the model told the sensor's
reading): the share of the uncompensated error removed; the share of hold-out poses whose
truth error is within 3 stated σ (pose_uncertainty with the model error) in every case; the
identification time. Then the adequacy test over NOISE_SEEDS noise draws per machine: how
often the χ² test fires when one effect class is left out of the identified model, and when
none is (false alarms), and which effect it names.

With ``--no-effects`` the machines are exactly of the identified model (the effects off;
nothing is left out to detect, so the detection and the measured-against-model targets are
not checked).

Run: .venv/bin/python benchmarks/calibration.py [--machines 5] [--no-effects]
Targets (exit 1 if one is not met): hold-out |Δp| RMS <= 10 µm and max <= 20 µm; after a
payload or air-temperature change >= 95 % of the uncompensated error removed; truth error
within 3 stated σ on >= 95 % of hold-out poses in every case (also the mover's own
statement in model mode: the calibration's uncertainty at the goal under the temperature in
use); adequacy test fires in >= 95 %
of trials with compliance, thermal or reversal left out, and passes in >= 95 % with none left
out (lead: reported, no target); measured mode within 2 stated σ on every hold-out pose and
its RMS below model mode's with compliance left out of the model; identification <= 2 s.
Printed beside the last: measured mode's stated σ over all hold-out poses pooled (the mean
square of the normalised error per axis, 1 when honest) and how often an honest σ would
itself leave a pose beyond 2σ (the every-pose target is a tail bound over 100 poses).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.identify import CalibrationData
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.poses import pose_error
from positioning_cell.mechanics.statics import Payload
from positioning_cell.motion.mover import Mover
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.parameters import parse
from positioning_cell.sim.campaign import Timing, measure_program
from positioning_cell.sim.effects.history import approach_directions, sequence_conditions
from positioning_cell.sim.encoders import EncoderSettings
from positioning_cell.sim.instant_cell import DRIVES_READY, InstantCell
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator
from positioning_cell.sim.truth import Truth

CONFIG = load_parameter_file(config_path())
SIM = parse(PoseMeasurementSettings, node_parameters(CONFIG, 'pose_measurement'))
POSITIONER = parse(PositionerSettings, node_parameters(CONFIG, 'positioner'))
ENCODERS = parse(EncoderSettings, node_parameters(CONFIG, 'leg_driver').get('encoder', {}))
MECH, PAYLOAD, STRUCTURE = SIM.mechanism, SIM.payload, SIM.structure
SAMPLES = 10
POSES, HOLD_OUT = 30, 20
APPROACH = 0.0005  # m, the intermediate pose below / above each pose
SECONDS_PER_MOVE = 15.0  # s per commanded move: two per pose (intermediate, pose) = 30 s
SESSIONS = (0.0, 4.0)  # h: the two calibration sessions' starts
HOLD_OUT_START = 2.0  # h
NOISE_SEEDS = 4  # noise draws per machine for the adequacy trials
PLANNING_COV = np.diag([3e-6**2] * 3 + [2e-5**2] * 3)  # one averaged pose (planning only)
PLANNING_JOINT_SIGMA = np.r_[[4e-7] * 3, [3e-6] * 3]
FULL = idf.IdentificationSettings()
GEOMETRY_ONLY = idf.IdentificationSettings(fit_compliance=False, fit_thermal=False,
                                           fit_lead=False, fit_reversal=False)
LEFT_OUT = ('compliance', 'thermal', 'reversal', 'lead')
LEAD_POWER = 10.0  # the lead error of the power trial, times the configured one
LEAD_POWER_CASE = f'lead x{LEAD_POWER:g}'


def simulator(seed: int, effects: bool, mass: float | None = None,
              lead_factor: float = 1.0) -> PoseMeasurementSimulator:
    """The seeded machine ``seed`` (geometry, drives and thermal seeds, and the tracker's
    registration: each machine is located anew, so the machines do not share one registration
    error) carrying ``mass``, its screws' lead error ``lead_factor`` times the configured
    one."""
    payload = PAYLOAD if mass is None else replace(PAYLOAD, mass=mass)
    truth = SIM.truth if effects else SIM.truth.without_effects()
    drives = replace(truth.drives, seed=seed,
                     lead_error_sigma=truth.drives.lead_error_sigma * lead_factor)
    truth = replace(truth, geometry_seed=seed, drives=drives,
                    thermal=replace(truth.thermal, seed=seed))
    return PoseMeasurementSimulator(replace(SIM, seed=seed, truth=truth, payload=payload))


def through_intermediates(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The poses' sequence with each reached through an intermediate pose APPROACH m below
    (even) or above (odd) it: positions (2N, 3) and which rows are the poses (2N,) bool."""
    side = np.where(np.arange(len(p)) % 2 == 0, -1.0, 1.0)
    inter = p + side[:, None] * np.array([0.0, 0.0, APPROACH])
    seq = np.stack([inter, p], axis=1).reshape(-1, 3)
    return seq, np.tile([False, True], len(p))


def nominal_commands(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    ik = inverse(MECH, p, q)
    return np.c_[ik.lengths, ik.thetas]


def calibration_run(sim: PoseMeasurementSimulator, p: np.ndarray, q: np.ndarray,
                    rng: np.random.Generator) -> CalibrationData:
    """The program measured in the two sessions (module docstring), the poses' data only."""
    assert sim.location is not None
    parts = []
    for s, start in enumerate(SESSIONS):
        rows = np.arange(s, len(p), len(SESSIONS))
        seq, is_pose = through_intermediates(p[rows])
        cmd = nominal_commands(seq, np.repeat(q[rows], 2, axis=0))
        data = measure_program(sim.truth, sim.instrument, sim.location.tracker, SIM.targets,
                               ENCODERS, cmd, rng, SAMPLES,
                               Timing(SECONDS_PER_MOVE, start * 3600.0))
        parts.append(data.subset(is_pose))
    return CalibrationData(*(None if parts[0][k] is None
                             else np.concatenate([part[k] for part in parts])
                             for k in range(len(parts[0]))))


class Moves(NamedTuple):
    """Hold-out moves judged on the truth: the truth errors (N, 3) m, (N, 3) rad."""

    e_p: np.ndarray
    e_r: np.ndarray


def hold_out_moves(truth: Truth, model: MachineModel | None, p: np.ndarray, q: np.ndarray,
                   rng: np.random.Generator, air_change: float = 0.0) -> Moves:
    """The hold-out poses visited through their intermediates from HOLD_OUT_START on, with
    the air ``air_change`` K from its course: commands from ``model`` (a MachineModel; None:
    nominal IK) told the sensor's reading and the planned approach, judged under the true
    conditions of the commanded sequence."""
    seq, is_pose = through_intermediates(p)
    q2 = np.repeat(q, 2, axis=0)
    times = HOLD_OUT_START * 3600.0 + SECONDS_PER_MOVE * np.arange(len(seq))
    thermal = truth.effects.thermal
    sensor = (np.full(len(seq), 20.0) if thermal is None else thermal.sensor(times, rng)) \
        + air_change
    planned = approach_directions(nominal_commands(seq, q2))
    if model is None:
        cmd = nominal_commands(seq, q2)
    else:
        out = model.commands(seq, q2, Conditions(temperature=sensor, approach=planned))
        cmd = np.c_[out.lengths, out.thetas]
    cond = sequence_conditions(thermal, cmd, times)
    cond = cond._replace(air=cond.air + air_change, legs=cond.legs + air_change)
    pick = type(cond)(cond.air[is_pose], cond.legs[is_pose], cond.approach[is_pose])
    true = truth.poses(cmd[is_pose, :3], cmd[is_pose, 3:], conditions=pick)
    e_p, e_r = pose_error(true.position, true.quaternion, p, q)
    return Moves(e_p, e_r)


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def worst(e: np.ndarray) -> float:
    return float(np.linalg.norm(e, axis=1).max())


def within_3_sigma(result: idf.Identification, payload: Payload, p: np.ndarray, q: np.ndarray,
                   e_p: np.ndarray) -> float:
    """The share of poses whose truth |Δp| is within 3 stated σ_p (with the model error)."""
    cov = idf.pose_uncertainty(result.x, result.covariance, MECH, payload, STRUCTURE, p, q,
                               model_error=result.model_error)
    sigma = np.sqrt(np.trace(cov[:, :3, :3], axis1=1, axis2=2))
    return float(np.mean(np.linalg.norm(e_p, axis=1) <= 3.0 * sigma))


def mover_mode(sim: PoseMeasurementSimulator, result: idf.Identification, p: np.ndarray,
               q: np.ndarray, seed: int, mode: str
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The positioner's own mover in ``mode``, the calibration loaded from its file, told the
    cell's air-temperature sensor reading before each move (Mover.air_temperature), moving the
    simulated machine (sim.instant_cell) to each pose: the truth |Δp| (N,) m and how far the
    truth is from where the move says it ended (its stated error) in its stated standard
    uncertainties, position and rotation (N, 2; inf without one); per axis that difference
    over its stated σ (N, 6) and the stated σ (N, 6) (NaN without one)."""
    assert sim.location is not None
    with tempfile.TemporaryDirectory() as folder:
        path = calfile.write(Path(folder) / 'calibration.yaml',
                             calfile.document(result, MECH, 1.0, {'benchmark': seed}))
        settings = replace(POSITIONER, settle_time=0.0, compensation=replace(
            POSITIONER.compensation, mode=mode, calibration_file=str(path)))
        cell = InstantCell(sim.truth, sim.instrument, sim.location.tracker, SIM.targets,
                           np.random.default_rng(200 + seed), settings.compensation.samples)
        cell.time = HOLD_OUT_START * 3600.0  # the hold-out's time of day (the air's course)
        mover = Mover(settings, cell.machine())
    mover.driver_status(DRIVES_READY)
    assert mover.estimate_pose() is not None  # the encoders have been read
    thermal = sim.truth.effects.thermal
    sensor_rng = np.random.default_rng(400 + seed)
    errors, ratios, normalised, sigmas = [], [], [], []
    for pk, qk in zip(p, q, strict=True):
        if thermal is not None:  # the cell's sensor reading now, with its stated uncertainty
            reading = float(thermal.sensor(np.array([cell.time]), sensor_rng)[0])
            tp = thermal.parameters
            assert mover.air_temperature(reading, tp.sensor_offset_sigma**2
                                         + tp.sensor_noise**2) == ''
        moved = mover.move('base', pk, qk)
        e_p, e_r = (e[0] for e in pose_error(*(a[None] for a in cell.true_pose()), pk[None],
                                             qk[None]))
        errors.append(float(np.linalg.norm(e_p)))
        if moved.uncertainty is None:  # no stated uncertainty (not measured mode)
            ratios.append((np.inf, np.inf))
            normalised.append(np.full(6, np.nan))
            sigmas.append(np.full(6, np.nan))
            continue
        difference = np.r_[e_p - moved.position_error, e_r - moved.orientation_error]
        normalised.append(difference / moved.uncertainty)
        sigmas.append(np.asarray(moved.uncertainty))
        # where the move says it ended (its measured error) against where it truly is
        ratios.append((float(np.linalg.norm(e_p - moved.position_error)
                             / np.linalg.norm(moved.uncertainty[:3])),
                       float(np.linalg.norm(e_r - moved.orientation_error)
                             / np.linalg.norm(moved.uncertainty[3:]))))
    return np.asarray(errors), np.asarray(ratios), np.asarray(normalised), np.asarray(sigmas)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--machines', type=int, default=5)
    parser.add_argument('--no-effects', action='store_true',
                        help='the machines without effects outside the identified model')
    args = parser.parse_args()
    effects = not args.no_effects
    settings = replace(prog.ProgramSettings(), poses=POSES, hold_out=HOLD_OUT)
    t0 = time.perf_counter()
    program = prog.choose(MECH, PAYLOAD, STRUCTURE, settings, PLANNING_COV, PLANNING_JOINT_SIGMA)
    print(f'program: {POSES} poses (+{HOLD_OUT} hold-out) chosen in '
          f'{time.perf_counter() - t0:.2f} s; effects outside the model '
          f'{"ON" if effects else "OFF"}; sessions at {SESSIONS} h, hold-out at '
          f'{HOLD_OUT_START} h, {2 * SECONDS_PER_MOVE:.0f} s per pose, each approached '
          f'through a pose {APPROACH * 1e3:.1f} mm below (even) / above (odd)')
    pp, pq = program.position, program.quaternion
    hp, hq = program.hold_out_position, program.hold_out_quaternion
    failures: list[str] = []
    print('\nhold-out truth |dp|, um: RMS / max; within 3 sigma: share of hold-out poses whose '
          'truth error is within 3 stated sigma')
    header = (f'{"mach":4s} {"uncomp":>13s} {"geometry-only":>13s} {"calibrated":>13s} '
              f'{"measured":>13s} {"3s":>4s} {"ident s":>7s} {"chi2/dof":>8s}  '
              f'{"changes: % removed (3s share)":s}')
    print(header)
    details: list[str] = []
    pooled: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for seed in range(args.machines):
        sim = simulator(seed, effects)
        data = calibration_run(sim, pp, pq, np.random.default_rng(100 + seed))
        t0 = time.perf_counter()
        result = idf.identify(MECH, PAYLOAD, STRUCTURE, data, FULL)
        t_ident = time.perf_counter() - t0
        geometry = idf.identify(MECH, PAYLOAD, STRUCTURE, data, GEOMETRY_ONLY)
        model = result.model(MECH, PAYLOAD, STRUCTURE)
        sensor_rng = 300 + seed
        moves = {
            'uncomp': hold_out_moves(sim.truth, None, hp, hq, np.random.default_rng(sensor_rng)),
            'geometry': hold_out_moves(sim.truth, geometry.model(MECH, PAYLOAD, STRUCTURE), hp,
                                       hq, np.random.default_rng(sensor_rng)),
            'calibrated': hold_out_moves(sim.truth, model, hp, hq,
                                         np.random.default_rng(sensor_rng)),
        }
        covered = within_3_sigma(result, PAYLOAD, hp, hq, moves['calibrated'].e_p)
        measured, ratios, normalised, sigmas = mover_mode(sim, result, hp, hq, seed, 'measured')
        pooled.append((ratios, normalised, sigmas))
        modelled, model_ratios, _, _ = mover_mode(sim, result, hp, hq, seed, 'model')
        model_covered = float(np.mean(model_ratios[:, 0] <= 3.0))
        cells = ' '.join(f'{rms(m.e_p) * 1e6:6.2f}/{worst(m.e_p) * 1e6:6.2f}'
                         for m in moves.values())
        cal = moves['calibrated'].e_p
        if rms(cal) > 10e-6 or worst(cal) > 20e-6:
            failures.append(f'machine {seed}: hold-out RMS {rms(cal) * 1e6:.2f} um, max '
                            f'{worst(cal) * 1e6:.2f} um (targets 10, 20)')
        if covered < 0.95:
            failures.append(f'machine {seed}: {covered * 100:.0f} % within 3 sigma')
        if ratios.max() > 2.0:
            failures.append(f'machine {seed}: measured mode {ratios.max():.2f}x its stated '
                            'uncertainty')
        if model_covered < 0.95:
            failures.append(f'machine {seed}: model mode {model_covered * 100:.0f} % within 3 '
                            'stated sigma')
        if t_ident > 2.0:
            failures.append(f'machine {seed}: identification {t_ident:.2f} s > 2 s')
        changes = []
        for label, mass, air in (('30kg', 30.0, 0.0), ('70kg', 70.0, 0.0), ('+5K', None, 5.0),
                                 ('-5K', None, -5.0)):
            other = sim if mass is None else simulator(seed, effects, mass)
            payload = PAYLOAD if mass is None else replace(PAYLOAD, mass=mass)
            none = hold_out_moves(other.truth, None, hp, hq, np.random.default_rng(sensor_rng),
                                  air)
            cal_c = hold_out_moves(other.truth, result.model(MECH, payload, STRUCTURE), hp, hq,
                                   np.random.default_rng(sensor_rng), air)
            removed = 1.0 - rms(cal_c.e_p) / rms(none.e_p)
            share = within_3_sigma(result, payload, hp, hq, cal_c.e_p)
            changes.append(f'{label} {removed * 100:5.1f}% ({share * 100:3.0f}%)')
            details.append(f'machine {seed} {label}: uncompensated {rms(none.e_p) * 1e6:.2f} um '
                           f'RMS, calibrated {rms(cal_c.e_p) * 1e6:.2f} um RMS / '
                           f'{worst(cal_c.e_p) * 1e6:.2f} um max')
            if removed < 0.95:
                failures.append(f'machine {seed} {label}: {removed * 100:.1f} % removed')
            if share < 0.95:
                failures.append(f'machine {seed} {label}: {share * 100:.0f} % within 3 sigma')
        print(f'{seed:<4d} {cells} {rms(measured[:, None]) * 1e6:6.2f}/'
              f'{measured.max() * 1e6:6.2f} {covered * 100:3.0f}% {t_ident:7.2f} '
              f'{result.chi2 / result.dof:8.2f}  ' + ', '.join(changes))
        rigid = idf.identify(MECH, PAYLOAD, STRUCTURE, data, replace(FULL, fit_compliance=False))
        rigid_model, rigid_measured = (mover_mode(sim, rigid, hp, hq, seed, mode)[0]
                                       for mode in ('model', 'measured'))
        details.append(
            f'machine {seed}: measured mode: truth from its stated end at most '
            f'{ratios[:, 0].max():.2f} sigma (position), {ratios[:, 1].max():.2f} (rotation), '
            f'median {np.median(ratios[:, 0]):.2f}, {np.median(ratios[:, 1]):.2f}; model mode '
            f'(the mover, {rms(modelled[:, None]) * 1e6:.2f} um RMS): truth within 3 stated '
            f'sigma on {model_covered * 100:.0f} % of poses, at most '
            f'{model_ratios[:, 0].max():.2f} sigma; compliance '
            f'left out of the model: mover mode model {rms(rigid_model[:, None]) * 1e6:.2f} um '
            f'RMS, measured {rms(rigid_measured[:, None]) * 1e6:.2f} um RMS; identified '
            f'{result.identifiability.rank} parameters, model error '
            f'{np.array2string(result.model_error * 1e6, precision=2)} um/urad, '
            f'adequate {result.adequacy.adequate if result.adequacy else "?"}; fixed: '
            + '; '.join(f'{k} (into {", ".join(n for n, _ in v) or "-"})'
                        for k, v in result.identifiability.merged.items()))
        if effects and rms(rigid_measured[:, None]) >= rms(rigid_model[:, None]):
            failures.append(f'machine {seed}: measured mode not below model mode with '
                            'compliance left out')
    print('\n' + '\n'.join(details))
    measured_honesty(pooled)
    adequacy_trials(args.machines, effects, pp, pq, failures)
    if failures:
        print('\nTARGETS NOT MET: ' + '; '.join(failures))
        return 1
    print('\nall targets met')
    return 0


def measured_honesty(pooled: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """Measured mode's stated σ over every machine's hold-out poses pooled: the mean square
    of (truth − stated end) / σ per axis (1 for an honest σ; the poses of one machine share
    its registration's error, so it scatters more than independent poses would), the poses
    beyond 2 stated σ, and how often an honest σ would leave at least one pose of as many
    beyond 2 σ (normal errors drawn with the stated σ's, independent axes, 4000 draws)."""
    ratios = np.concatenate([r for r, _, _ in pooled])
    z = np.concatenate([n for _, n, _ in pooled])
    sigma = np.concatenate([s for _, _, s in pooled])
    draws = np.random.default_rng(7).standard_normal((4000, *sigma.shape)) * sigma
    honest = np.stack([np.linalg.norm(draws[..., k], axis=-1)
                       / np.linalg.norm(sigma[:, k], axis=-1)
                       for k in (slice(0, 3), slice(3, 6))], axis=-1)
    chance = float(np.mean(np.any(honest > 2.0, axis=(1, 2))))
    print(f'\nmeasured mode, {len(z)} hold-out poses pooled: mean square of (truth - stated '
          'end) / stated sigma per axis x y z rx ry rz '
          f'{np.array2string(np.mean(z**2, axis=0), precision=2)} (1: honest); beyond 2 '
          f'stated sigma: {int(np.sum(np.any(ratios > 2.0, axis=1)))} of {len(z)} poses '
          f'(largest {ratios.max():.2f}); an honest sigma leaves at least one of {len(z)} '
          f'poses beyond 2 sigma in {chance * 100:.0f} % of draws')


def adequacy_trials(machines: int, effects: bool, pp: np.ndarray, pq: np.ndarray,
                    failures: list[str]) -> None:
    """The χ² test with each class left out and with none, NOISE_SEEDS draws per machine;
    and the lead left out of a machine whose screws' lead error is LEAD_POWER times the
    configured one (what the test can see of a lead error above the noise)."""
    fired: dict[str, list[bool]] = {k: [] for k in ('none', *LEFT_OUT, LEAD_POWER_CASE)}
    named: dict[str, dict[str, int]] = {k: {} for k in fired}
    for seed in range(machines):
        sims = {1.0: simulator(seed, effects), LEAD_POWER: simulator(seed, effects,
                                                                     lead_factor=LEAD_POWER)}
        for noise in range(NOISE_SEEDS):
            runs = {factor: calibration_run(sim, pp, pq,
                                            np.random.default_rng(1000 * (noise + 1) + seed))
                    for factor, sim in sims.items()}
            for case, hits in fired.items():
                left = 'lead' if case == LEAD_POWER_CASE else case
                s = FULL if case == 'none' else replace(FULL, **{f'fit_{left}': False})
                data = runs[LEAD_POWER if case == LEAD_POWER_CASE else 1.0]
                verdict = idf.identify(MECH, PAYLOAD, STRUCTURE, data, s).adequacy
                assert verdict is not None
                hits.append(not verdict.adequate)
                if verdict.suspects:
                    name = verdict.suspects[0].effect
                    named[case][name] = named[case].get(name, 0) + 1
    print(f'\nadequacy (chi2 test, p < {FULL.adequacy_p}), {machines} machines x {NOISE_SEEDS} '
          'noise draws:')
    for case, hits in fired.items():
        rate = float(np.mean(hits))
        label = 'false alarms' if case == 'none' else 'detected'
        names = ', '.join(f'{k} {v}' for k, v in sorted(named[case].items(),
                                                          key=lambda kv: -kv[1])) or '-'
        print(f'  left out {case:10s}: {label} {rate * 100:5.1f} % of {len(hits)}; named first: '
              f'{names}')
        if case == 'none' and rate > 0.05:
            failures.append(f'adequacy false alarms {rate * 100:.0f} % > 5 %')
        elif effects and case in ('compliance', 'thermal', 'reversal') and rate < 0.95:
            failures.append(f'adequacy detects {case} left out in {rate * 100:.0f} % < 95 %')


if __name__ == '__main__':
    sys.exit(main())
