"""The work of ``predict_accuracy`` (:mod:`positioning_cell.tools.predict_accuracy`: the
command line): :func:`predict` (tests call it), :func:`calibrated_prediction`, the printed
tables; imported once the command line is parsed."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.identify import pose_uncertainty
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.limits import require_within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError, PositioningError
from positioning_cell.motion.settings import machine_settings
from positioning_cell.prediction.angular import (
    PAPER_EXAMPLES,
    PAPER_HOLES,
    PAPER_PARTS,
    AngleFits,
    Strategy,
    assembly_angles,
    draw_part_tilts,
    fit_angle_distribution,
    normal_angles,
    rice_law,
)
from positioning_cell.prediction.extremes import WorstNorm, worst_norm
from positioning_cell.prediction.figures import (
    plot_angle_fits,
    plot_stacked_stages,
    plot_workspace_maps,
)
from positioning_cell.prediction.maps import workspace_maps
from positioning_cell.prediction.montecarlo import (
    Comparison,
    YieldEstimate,
    compare,
    estimate_yield,
    inside_requirement,
    monte_carlo,
)
from positioning_cell.prediction.sensitivity import (
    COORDINATES,
    Linearisation,
    linearise,
    split_norms,
    worst_case,
)
from positioning_cell.prediction.sources import ToleranceSpec, load_tolerance_spec
from positioning_cell.tools.exits import Exit

FloatArray = NDArray[np.float64]
NODE_NAME = 'predict_accuracy'


@dataclass(frozen=True)
class PredictionReport:
    """What :func:`predict` found: the linearisation at the pose, the comparison (per
    coordinate, m and rad), the largest |Δp| (m) and rotation angle (rad) over the tolerance set
    (every clearance direction in the ``any`` gap model) with their certified bounds, the yields
    (nonlinear and linear model on the same samples), the angle fits, the printed text and the
    files written."""

    spec: ToleranceSpec
    linearisation: Linearisation
    comparison: Comparison
    worst_position: WorstNorm
    worst_orientation: WorstNorm
    yield_nonlinear: YieldEstimate
    yield_linear: YieldEstimate
    converged: int
    angle_fits: AngleFits
    text: str
    files: tuple[Path, ...] = field(default_factory=tuple)


def load_mechanism(path: Path) -> Mechanism:
    """The ``mechanism:`` block of a ROS 2 parameter file (``/**`` or ``predict_accuracy``)."""
    params = node_parameters(load_parameter_file(path), NODE_NAME)
    block = params.get('mechanism')
    if not isinstance(block, dict):
        raise ConfigError(f'{path}: no mechanism block under ros__parameters')
    return Mechanism.from_params(block)


def shipped_config(name: str) -> Path:
    """Path of a shipped config file. ``config.share_directory`` lets ament's OSError through
    when AMENT_PREFIX_PATH is unset (outside a sourced ROS environment); then the source tree's
    ``config/`` is used, as share_directory intends for checkouts and editable installs."""
    try:
        return config_path(name)
    except OSError:
        path = Path(__file__).resolve().parents[2] / 'config' / name
        if not path.is_file():
            raise ConfigError(f'shipped config file {name!r} not found at {path}') from None
        return path


def predict(out_dir: Path, *, config: Path | None = None, spec_path: Path | None = None,
            position: Sequence[float] | None = None,
            rotvec: Sequence[float] = (0.0, 0.0, 0.0), samples: int = 1_000_000,
            seed: int = 0, grid: int = 21, half_width: float = 0.05,
            stacked_runs: int = 10_000, global_runs: int = 1_000) -> PredictionReport:
    """Run the whole prediction and write the figures and ``summary.txt`` into ``out_dir``.

    ``position`` (m, base frame; default home) and ``rotvec`` (rad, rotation vector of the
    platform orientation) give the pose; ``samples`` Monte Carlo samples from a generator seeded
    with ``seed``; a ``grid`` × ``grid`` workspace map over ±``half_width`` m (0: none); the
    seed 003 stacked-stage study with ``stacked_runs`` runs (``global_runs`` for the exhaustive
    global strategy; 0: no study). Raises ConfigError / InputError / LimitError.
    """
    if samples < 2:
        raise InputError(f'samples = {samples}: need at least 2 Monte Carlo samples')
    mech = load_mechanism(config if config is not None else shipped_config('cell.yaml'))
    spec = load_tolerance_spec(spec_path if spec_path is not None
                               else shipped_config('tolerances.yaml'), mech)
    p = mech.home_position if position is None else np.asarray(position, dtype=float)
    q = Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_quat()
    require_within_limits(mech, p, q)
    rng = np.random.default_rng(seed)
    out_dir.mkdir(parents=True, exist_ok=True)

    lin = linearise(mech, spec, p, q)
    worst = (worst_norm(lin.matrix[0, :3], spec.bounds, spec.balls),
             worst_norm(lin.matrix[0, 3:], spec.bounds, spec.balls))
    result = monte_carlo(mech, spec, p, q, samples, rng)
    comparison = compare(lin, spec, result)
    yields = (estimate_yield(inside_requirement(result.deviations, spec.requirement)),
              estimate_yield(inside_requirement(result.linear, spec.requirement)))
    ok = result.converged
    angles = normal_angles(Rotation.from_rotvec(result.deviations[ok, 3:]))
    fits = fit_angle_distribution(angles)
    files = [plot_angle_fits(angles, fits, out_dir / 'angle_fit.png',
                             'platform-normal angle error at the prediction pose')]
    lines = [f'predict_accuracy: pose p = {_mm(p)} mm, rotation vector = {list(rotvec)} rad',
             f'tolerance spec: {len(spec.sources)} sources; requirement |dp| <= '
             f'{spec.requirement.position * 1e6:.1f} um, angle <= '
             f'{spec.requirement.orientation * 1e3:.3f} mrad; gap connectors: {spec.gap.mode}',
             '', *_sensitivity_table(lin, spec), '', *_kind_table(lin, spec), '',
             *_comparison_table(comparison, result.deviations[ok], worst, spec), '',
             f'Monte Carlo: {samples} samples, nonlinear closure model, {int(ok.sum())} solved',
             _yield_line('yield (nonlinear model)', yields[0]),
             _yield_line('yield (linear model T.x, same samples)', yields[1]), '',
             *_fit_lines('platform-normal angle', fits)]
    if grid > 0:
        maps = workspace_maps(mech, spec, half_width, grid)
        files += plot_workspace_maps(maps, out_dir)
        lines += ['', f'workspace maps ({grid} x {grid} poses, +/-{half_width * 1e3:.0f} mm at '
                  f'z = {maps.z * 1e3:.1f} mm): worst-case |dp| '
                  f'{np.nanmin(maps.worst_position) * 1e6:.1f}..'
                  f'{np.nanmax(maps.worst_position) * 1e6:.1f} um, worst-case angle '
                  f'{np.nanmin(maps.worst_orientation) * 1e3:.2f}..'
                  f'{np.nanmax(maps.worst_orientation) * 1e3:.2f} mrad']
    if stacked_runs > 0:
        stacked_lines, path = _stacked_study(out_dir, stacked_runs, global_runs, rng)
        lines += ['', *stacked_lines]
        files.append(path)
    text = '\n'.join(lines) + '\n'
    summary = out_dir / 'summary.txt'
    summary.write_text(text)
    files.append(summary)
    return PredictionReport(spec, lin, comparison, worst[0], worst[1], yields[0], yields[1],
                            int(ok.sum()), fits, text, tuple(files))


def _mm(v: FloatArray) -> str:
    return '(' + ', '.join(f'{x * 1e3:.3f}' for x in v) + ')'


def _sensitivity_table(lin: Linearisation, spec: ToleranceSpec) -> list[str]:
    head = (f'{"source":<18}{"bound":>12}' + ''.join(f'{c:>10}' for c in COORDINATES))
    lines = ['sensitivity T = -[I 0] U^-1 A at the pose (seed 004 eq. 14); columns x y z in '
             'm per source unit, rx ry rz in rad per source unit', head]
    for j, src in enumerate(spec.sources):
        bound = (f'{src.bound * 1e6:8.2f} um' if src.unit == 'm'
                 else f'{src.bound * 1e6:6.2f} urad')
        lines.append(f'{src.name:<18}{bound:>12}'
                     + ''.join(f'{v:10.4f}' for v in lin.matrix[0, :, j]))
    return lines


def _kind_table(lin: Linearisation, spec: ToleranceSpec) -> list[str]:
    lines = ['worst-case contribution by kind of source, sum |T_i| x_i (+ r |T_j| per clearance '
             'ball) (um for x y z, urad for rx ry rz)',
             f'{"kind":<18}' + ''.join(f'{c:>10}' for c in COORDINATES)]
    for kind in dict.fromkeys(spec.kinds):
        bounds = np.where([k == kind for k in spec.kinds], spec.bounds, 0.0)
        lines.append(f'{kind:<18}' + ''.join(
            f'{v * 1e6:10.2f}' for v in worst_case(lin.matrix[0], bounds, spec.balls)))
    return lines


def _comparison_table(c: Comparison, deviations: FloatArray,
                      worst: tuple[WorstNorm, WorstNorm], spec: ToleranceSpec) -> list[str]:
    names = ('worst case (eq. 15)', 'RSS of bounds', 'linear 3 sigma', 'MC max |dev|',
             'MC 3 sigma', 'MC 99.73 % |dev|')
    rows = (c.worst_case, c.rss, c.linear_3sigma, c.mc_max, c.mc_3sigma, c.mc_q9973)
    lines = ['worst case vs RSS vs Monte Carlo per coordinate (um for x y z, urad for rx ry rz)',
             f'{"":<22}' + ''.join(f'{k:>10}' for k in COORDINATES)]
    lines += [f'{n:<22}' + ''.join(f'{v * 1e6:10.2f}' for v in r)
              for n, r in zip(names, rows, strict=True)]
    axes = split_norms(c.worst_case)
    pos = np.linalg.norm(deviations[:, :3], axis=1)
    ang = np.linalg.norm(deviations[:, 3:], axis=1)
    directions = ('every direction' if spec.gap.mode == 'any'
                  else f'directions: {spec.gap.mode} only, not a bound of all directions')
    lines += [f'largest |dp| and angle over the tolerance set (clearance {directions}): '
              'attained <= max <= certified bound',
              f'|dp|:  worst case {worst[0].attained * 1e6:.2f} um (bound '
              f'{worst[0].bound * 1e6:.2f}; norm of per-axis worst cases {axes[0] * 1e6:.2f}), '
              f'MC max {pos.max() * 1e6:.2f} um, MC 99.73 % {np.quantile(pos, 0.9973) * 1e6:.2f} '
              'um',
              f'angle: worst case {worst[1].attained * 1e3:.4f} mrad (bound '
              f'{worst[1].bound * 1e3:.4f}; norm of per-axis worst cases {axes[1] * 1e3:.4f}), '
              f'MC max {ang.max() * 1e3:.4f} mrad, MC 99.73 % '
              f'{np.quantile(ang, 0.9973) * 1e3:.4f} mrad']
    if spec.balls:
        unit = [(spec.sources[a], worst[0].sources[a:b] / spec.bounds[a]) for a, b in spec.balls]
        gaps = ', '.join(f'{src.kind[0].upper()}{src.leg} ({", ".join(f"{v:+.2f}" for v in e)})'
                         for src, e in unit)
        lines.append(f'worst |dp| gap directions (offset / r; U base frame, S platform frame): '
                     f'{gaps}')
    return lines


def _yield_line(label: str, y: YieldEstimate) -> str:
    return (f'{label}: {y.probability * 100:.3f} % ({y.inside}/{y.trials}), '
            f'{y.confidence * 100:.0f} % CI [{y.low * 100:.3f}, {y.high * 100:.3f}] %')


def _fit_lines(what: str, fits: AngleFits) -> list[str]:
    nu, sigma = fits.rice_nu_sigma
    c, loc, scale = fits.gev.params
    return [f'{what} fits ({fits.rice.samples} samples, KS statistic D / p-value):',
            f'  Rice(nu = {nu * 1e3:.4f} mrad, sigma = {sigma * 1e3:.4f} mrad): '
            f'D = {fits.rice.ks_statistic:.4f}, p = {fits.rice.ks_pvalue:.3g}',
            f'  GEV(c = {c:.4f}, loc = {loc * 1e3:.4f} mrad, scale = {scale * 1e3:.4f} mrad): '
            f'D = {fits.gev.ks_statistic:.4f}, p = {fits.gev.ks_pvalue:.3g}']


def _stacked_study(out_dir: Path, runs: int, global_runs: int,
                   rng: np.random.Generator) -> tuple[list[str], Path]:
    from scipy.stats import kstest

    curves: dict[int, dict[Strategy, FloatArray]] = {}
    lines = [f'seed 003 stacked stages: k = {PAPER_HOLES}, {PAPER_PARTS} parts, {runs} runs '
             f'({min(global_runs, runs)} for the exhaustive global search); paper values read '
             'as mrad; mean angle (mrad) for n = 1..8']
    for example, (mean, std) in PAPER_EXAMPLES.items():
        tilts = draw_part_tilts(runs, PAPER_PARTS, mean, std, rng)
        curves[example] = {
            Strategy.DIRECT: assembly_angles(tilts, PAPER_HOLES, Strategy.DIRECT),
            Strategy.STAGE_BY_STAGE: assembly_angles(tilts, PAPER_HOLES, Strategy.STAGE_BY_STAGE)}
        if global_runs > 0:
            curves[example][Strategy.GLOBAL] = assembly_angles(
                tilts[:global_runs], PAPER_HOLES, Strategy.GLOBAL)
        lines.append(f'example {example}: dalpha, dbeta ~ N({mean * 1e3:g}, {std * 1e3:g}) mrad')
        for strategy, angles in curves[example].items():
            lines.append(f'  {strategy.value:<15}'
                         + ' '.join(f'{v * 1e3:7.3f}' for v in angles.mean(axis=0)))
        final = curves[example][Strategy.DIRECT][:, -1]
        nu, sigma = np.sqrt(2.0) * PAPER_PARTS * mean, np.sqrt(PAPER_PARTS) * std
        fit = fit_angle_distribution(final)
        fnu, fsigma = fit.rice_nu_sigma
        lines.append(f'  direct, n = {PAPER_PARTS}: paper Rice({nu * 1e3:.4f}, {sigma * 1e3:.4f})'
                     f' mrad, KS p = {kstest(final, rice_law(nu, sigma).cdf).pvalue:.3g}; '
                     f'fitted Rice({fnu * 1e3:.4f}, {fsigma * 1e3:.4f}) mrad')
    return lines, plot_stacked_stages(curves, out_dir / 'stacked_stages.png')


def calibrated_prediction(calibration: Path, config: Path | None = None,
                          position: Sequence[float] | None = None,
                          rotvec: Sequence[float] = (0.0, 0.0, 0.0)) -> str:
    """The calibrated machine's predicted accuracy at the pose: the standard uncertainty of
    where it puts the platform, from the identified parameters' covariance of the calibration
    file (:func:`positioning_cell.calibration.identify.pose_uncertainty`), for the config's
    mechanism and payload. CalibrationFileError for a file of another machine."""
    machine = machine_settings(config or shipped_config('cell.yaml'))
    mech = machine.mechanism
    cal = calfile.load(calibration, mech)
    p = mech.home_position if position is None else np.asarray(position, dtype=float)
    q = Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_quat()
    require_within_limits(mech, p, q)
    cov = pose_uncertainty(cal.x, cal.covariance, mech, machine.payload, machine.structure,
                           p, q, cal.seating_force, model_error=cal.model_error)[0]
    sigma = np.sqrt(np.diag(cov))
    source = ' and the model error' if cal.model_error.any() else ''
    return (f'calibrated machine ({calibration}): standard uncertainty at the pose from the '
            f'identified parameters{source}: position x, y, z '
            f'{np.round(sigma[:3] * 1e6, 3).tolist()} '
            f'um (|dp| {np.linalg.norm(sigma[:3]) * 1e6:.3f} um), rotation '
            f'{np.round(sigma[3:] * 1e6, 2).tolist()} urad\n')


def run(args: argparse.Namespace) -> int:
    """Run ``predict_accuracy`` with parsed command-line ``args``; its exit code."""
    try:
        if args.calibration is not None:
            sys.stdout.write(calibrated_prediction(args.calibration, args.config,
                                                   args.position, args.rotvec))
        report = predict(args.out, config=args.config, spec_path=args.spec,
                         position=args.position, rotvec=args.rotvec, samples=args.samples,
                         seed=args.seed, grid=args.grid, half_width=args.half_width,
                         stacked_runs=args.stacked_runs, global_runs=args.global_runs)
    except PositioningError as err:
        print(f'predict_accuracy: error: {err}', file=sys.stderr)
        return Exit.USAGE
    sys.stdout.write(report.text)
    print('wrote: ' + ', '.join(str(f) for f in report.files))
    return Exit.OK
