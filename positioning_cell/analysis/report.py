"""The analysis of a run for people (Markdown, µm and degrees) and for programs (JSON, SI)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from positioning_cell.accuracy import ErrorStatistics
from positioning_cell.analysis.accuracy_map import MAP_LEAST, map_summary, mapped, pose_at
from positioning_cell.analysis.compliance_test import markdown as compliance_table
from positioning_cell.analysis.error_budget import CONTRIBUTIONS, Contribution, ErrorBudget
from positioning_cell.analysis.replay import OUTSIDE_PROGRAM
from positioning_cell.analysis.summary import ModeSummary, PoseSummary, RunAnalysis
from positioning_cell.analysis.tables import markdown_table

REPORT_FILE = 'report.md'
SUMMARY_FILE = 'summary.json'


def um(value: float | None) -> str:
    """A length in m as µm for people, one decimal ('n/a' for None)."""
    return 'n/a' if value is None else f'{value * 1e6:.1f}'


def um_u(value: float | None, uncertainty: float) -> str:
    """A length in m with its expanded uncertainty as µm for people: ``12.3 ± 4.1`` (``± ?``
    when not stated)."""
    u = f'{uncertainty * 1e6:.1f}' if math.isfinite(uncertainty) else '?'
    return 'n/a' if value is None else f'{value * 1e6:.1f} ± {u}'


def s_u(value: float, uncertainty: float) -> str:
    """A time in s with its expanded uncertainty for people: ``0.25 ± 0.04`` (``± ?`` when
    not stated, 'n/a' for NaN)."""
    u = f'{uncertainty:.2f}' if math.isfinite(uncertainty) else '?'
    return 'n/a' if not math.isfinite(value) else f'{value:.2f} ± {u}'


def deg_u(value: float | None, uncertainty: float) -> str:
    """An angle in rad with its expanded uncertainty as degrees for people: ``0.1234 ±
    0.0021`` (``± ?`` when not stated)."""
    u = f'{math.degrees(uncertainty):.4f}' if math.isfinite(uncertainty) else '?'
    return 'n/a' if value is None else f'{math.degrees(value):.4f} ± {u}'


def deg(value: float | None) -> str:
    """An angle in rad as degrees for people, four decimals ('n/a' for None)."""
    return 'n/a' if value is None else f'{math.degrees(value):.4f}'


COMPARISON_HEADER = ('mode', 'visits', 'in tol.', 'C/I/N', 'max |Δp| µm', 'RMS |Δp| µm',
                     'max angle °', 'RMS angle °', 'worst AP_p µm', 'worst RP_l µm',
                     'worst AP_abc °', 'worst RP_abc °', 'settle s (mean/max)')


def comparison_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    """One row per mode: the comparison table (µm, degrees, s; ``in tol.`` the errors as
    measured, ``C/I/N`` the visits that conform, are indeterminate, do not conform by the
    monitor's decision rule: docs/howto/verdicts.md)."""
    return [[m.mode, str(m.extremes.n), f'{m.extremes.within_tolerance}/{m.extremes.n}',
             decided(m.extremes.decisions), um(m.extremes.position_error_max),
             um(m.extremes.position_error_rms),
             deg(m.extremes.orientation_error_max), deg(m.extremes.orientation_error_rms),
             um(m.ap_p_max), um(m.rp_l_max), deg(m.ap_angle_max), deg(m.rp_angle_max),
             f'{m.extremes.settle_time_mean:.2f}/{m.extremes.settle_time_max:.2f}']
            for m in modes]


def decided(counts: Mapping[str, int]) -> str:
    """``conforms/indeterminate/does not conform`` counts as ``C/I/N``."""
    return f'{counts["conforms"]}/{counts["indeterminate"]}/{counts["does_not_conform"]}'


def comparison_table(modes: Sequence[ModeSummary]) -> str:
    """The per-mode comparison as fixed-width text (for a terminal)."""
    rows = [list(COMPARISON_HEADER), *comparison_rows(modes)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COMPARISON_HEADER))]
    return '\n'.join('  '.join(c.rjust(w) if i else c.ljust(w)
                               for i, (c, w) in enumerate(zip(r, widths, strict=True)))
                     for r in rows) + '\n'


def _pose_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    rows = []
    for m in modes:
        for p in m.poses:
            f, e, u, o = p.figures, p.extremes, p.uncertainty, p.orientation_uncertainty
            rows.append([m.mode, p.pose, str(f.n),
                         ', '.join(f'{v * 1e3:.3f}' for v in f.commanded_position),
                         um_u(f.ap_p, u.ap_p), um(f.ap_x), um(f.ap_y), um(f.ap_z),
                         um_u(f.rp_l, u.rp_l),
                         deg_u(f.ap_a, o.ap_a), deg_u(f.ap_b, o.ap_b), deg_u(f.ap_c, o.ap_c),
                         deg_u(f.rp_a, o.rp_a), deg_u(f.rp_b, o.rp_b), deg_u(f.rp_c, o.rp_c),
                         um(e.position_error_max), um(e.position_error_rms),
                         deg(e.orientation_error_max), deg(e.orientation_error_rms),
                         f'{e.settle_time_mean:.2f}/{e.settle_time_max:.2f}',
                         f'{e.within_tolerance}/{e.n}'])
    return rows


MULTIDIRECTIONAL_HEADER = ('mode', 'pose', 'directions', 'visits', 'vAP_p ± U µm',
                           'vAP_a ± U °', 'vAP_b ± U °', 'vAP_c ± U °')
DISTANCE_HEADER = ('mode', 'poses', 'cycles', 'commanded D mm', 'AD_p ± U µm', 'RD_p ± U µm')


STABILISATION_HEADER = ('mode', 'pose', 'cycles', 'unresolved', 't mean ± U s', 't max s',
                        'OV mean ± U µm', 'OV max µm')


MAP_HEADER = ('mode', 'poses', 'x mm', 'y mm', 'z mm', 'AP_p mean µm', 'worst AP_p ± U µm',
              'at', 'RP_l mean µm', 'worst RP_l ± U µm', 'at')


def _map_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    """The accuracy map's row of each mapped mode: the box of its poses, AP_p and RP_l mean
    and worst, with the worst pose's U and position."""
    rows = []
    for m in mapped(modes):
        s = map_summary(m)
        box = [f'{lo * 1e3:.1f} … {hi * 1e3:.1f}' for lo, hi in zip(s.low, s.high,
                                                                     strict=True)]
        worst_ap = pose_at(m, s.ap_p_worst)
        worst_rp = pose_at(m, s.rp_l_worst) if s.rp_l_worst else None
        rows.append([m.mode, str(s.poses), *box, um(s.ap_p_mean),
                     um_u(s.ap_p_max, worst_ap.uncertainty.ap_p),
                     _at(worst_ap), um(s.rp_l_mean) if math.isfinite(s.rp_l_mean) else 'n/a',
                     um_u(s.rp_l_max, worst_rp.uncertainty.rp_l) if worst_rp else 'n/a',
                     _at(worst_rp) if worst_rp else ''])
    return rows


def _at(pose: PoseSummary) -> str:
    """A pose's name and commanded position in mm."""
    x, y, z = (v * 1e3 for v in pose.figures.commanded_position)
    return f'{pose.pose} ({x:.1f}, {y:.1f}, {z:.1f})'


def _stabilisation_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    rows = []
    for m in modes:
        for p in m.poses:
            if (f := p.stabilisation) is None:
                continue
            rows.append([m.mode, p.pose, str(f.cycles), str(f.unresolved),
                         s_u(f.time_mean, f.time_u), f'{f.time_max:.2f}',
                         um_u(f.overshoot_mean if math.isfinite(f.overshoot_mean) else None,
                              f.overshoot_u),
                         um(f.overshoot_max if math.isfinite(f.overshoot_max) else None)])
    return rows


def _drift_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    rows = []
    for m in modes:
        for p in m.poses:
            if (d := p.drift) is None:
                continue
            rows.append([m.mode, p.pose, str(d.cycles), f'{d.span:.0f}',
                         um_u(d.dap_p, d.u_dap_p), um_u(d.drp_l, d.u_drp_l),
                         *(deg_u(*d.figure(name)) for name in ('ap_a', 'ap_b', 'ap_c')),
                         *(deg_u(*d.figure(name)) for name in ('rp_a', 'rp_b', 'rp_c'))])
    return rows


def _percent_u(value: float | None, uncertainty: float) -> str:
    """A share (a fraction) with its U as percent for people ('n/a', '± ?')."""
    u = f'{uncertainty * 100:.2f}' if math.isfinite(uncertainty) else '?'
    return 'n/a' if value is None else f'{value * 100:+.2f} ± {u}'


def _path_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    rows = []
    for m in modes:
        for p in m.paths:
            f, v = p.figures, p.velocity
            speed = ['n/a'] * 4 if v is None else [
                f'{v.commanded * 1e3:.2f}', _percent_u(v.av, v.u_av), _percent_u(v.rv, v.u_rv),
                _percent_u(v.fv, v.u_fv)]
            t = p.positioning
            rows.append([m.mode, p.name, str(f.n), f'{f.length * 1e3:.1f}', str(len(f.planes)),
                         um_u(f.at_p, f.u_at_p), um_u(f.rt_l, f.u_rt_l), *speed,
                         'n/a' if t is None else f'{t.mean:.2f} ± {t.u:.2f}'])
    return rows


def _distance_rows(modes: Sequence[ModeSummary]) -> list[list[str]]:
    rows = []
    for m in modes:
        if m.distance is None:
            continue
        d, f, u = m.distance, m.distance.figures, m.distance.uncertainty
        rows.append([m.mode, ' - '.join(d.poses), str(f.n), f'{f.commanded_distance * 1e3:.3f}',
                     um_u(f.ad_p, u.ad_p), um_u(f.rd_p, u.rd_p)])
    return rows


#: AP and RP with their U (k = 2) from the measurement (analysis.summary.PoseSummary).
POSE_HEADER = ('mode', 'pose', 'n', 'commanded x, y, z mm', 'AP_p ± U µm', 'AP_x', 'AP_y',
               'AP_z', 'RP_l ± U µm', 'AP_a ± U °', 'AP_b ± U °', 'AP_c ± U °',
               'RP_a ± U (±°)', 'RP_b ± U (±°)', 'RP_c ± U (±°)',
               'max |Δp| µm', 'RMS |Δp| µm', 'max angle °', 'RMS angle °', 'settle s',
               'in tol.')


PATH_HEADER = ('mode', 'path', 'cycles', 'length mm', 'planes', 'AT_p ± U µm', 'RT_l ± U µm',
               'v_c mm/s', 'AV ± U %', 'RV ± U %', 'FV ± U %', 't_pos ± U s')


DRIFT_HEADER = ('mode', 'pose', 'n', 'T s', 'dAP_p ± U µm', 'dRP_l ± U µm', 'dAP_a ± U °',
                'dAP_b ± U °', 'dAP_c ± U °', 'dRP_a ± U °', 'dRP_b ± U °', 'dRP_c ± U °')


BUDGET_HEADER = ('mode', 'visits', 'truth RMS µm', *CONTRIBUTIONS)


def _budget_cell(c: Contribution) -> str:
    if c.rms is None:
        return 'n/a'
    size = f'{c.rms * 1e6:.2f}'
    if not c.in_chain:
        return f'{size} (—)'
    return size if c.share is None else f'{size} ({c.share * 100:.0f} %)'


def _budget_row(b: ErrorBudget) -> list[str]:
    """One mode's budget for people (µm, %)."""
    return [b.mode, str(b.visits), 'n/a' if b.truth_rms is None else f'{b.truth_rms * 1e6:.2f}',
            *(_budget_cell(b.contribution(name)) for name in CONTRIBUTIONS)]


def _tracker_line(label: str, stats: ErrorStatistics | None) -> str:
    if stats is None:
        return f'- {label}: no measurement paired with a true pose'
    return (f'- {label}: {stats.samples} pairs, |Δp| RMS {um(stats.rms_position_error)} µm, '
            f'max {um(stats.max_position_error)} µm; angle RMS '
            f'{deg(stats.rms_orientation_error)}°, max {deg(stats.max_orientation_error)}°')


def markdown(analysis: RunAnalysis, plots: Sequence[Path] = ()) -> str:
    """The Markdown report."""
    a, s = analysis, analysis.settings
    out = [f'# Positioning cell run: {a.bag.name}', '',
           f'Bag `{a.bag}`: {a.message_count} messages, {len(a.topics)} topics.',
           f'Tolerances: position {um(s.tolerance.position)} µm, orientation '
           f'{deg(s.tolerance.orientation)}°. Settle: window {s.settle.window} s, dwell '
           f'{s.settle.dwell} s, ≥ {s.settle.min_samples} samples, spread ≤ '
           f'{um(s.settle.position_threshold)} µm / {deg(s.settle.angle_threshold)}°.', '']
    if a.problems:
        out += ['## Problems', '', *(f'- {p}' for p in a.problems), '']
    described = a.description.lines()
    out += ['## The run as the bag describes it', '', *(described or [
        '- the bag holds no description (recorded before bags described themselves, or by '
        'another recorder)']), '']
    if a.missing_optional:
        out += [f'Not in the bag (figures that need them are left out): '
                f'{", ".join(a.missing_optional)}.', '']
    if a.replay.notes:
        out += ['## Notes', '', *(f'- {n}' for n in a.replay.notes), '']
    if a.ignored:
        out += [f'{len(a.ignored)} message(s) ignored as the live monitor ignores them; '
                f'first: {a.ignored[0].topic}: {a.ignored[0].reason}.', '']
    before = sum(v.mode == OUTSIDE_PROGRAM for v in a.replay.visits)
    if before:
        out += [f'{before} visit(s) outside the program (homing, calibration) are in the live '
                'monitor\'s figures only, not in the comparison of modes.', '']
    out += ['## Comparison of compensation modes (measured by the tracker)', '']
    if a.modes:
        out += markdown_table(COMPARISON_HEADER, comparison_rows(a.modes))
    else:
        out += ['No commanded pose settled: nothing to compare.']
    out += ['', 'AP, RP: ISO 9283:1998 §7.2.1 pose accuracy and §7.2.2 repeatability over the '
            'cycles of each pose (RP needs two cycles); Δp and angle: attained (settle-window '
            'mean) minus commanded pose; settle: target (or the bag\'s first sample, if the '
            'target is older) to end of the settle window.', '']
    if a.modes:
        out += ['## Per commanded pose', '', *markdown_table(POSE_HEADER, _pose_rows(a.modes)),
                '', 'U: expanded uncertainty (k = 2) from the covariance each visit was '
                'measured with; it cannot understate (docs/howto/verdicts.md).', '']
    varied = [(m.mode, p) for m in a.modes for p in m.poses if p.multidirectional is not None]
    if varied:
        out += ['## Multi-directional pose accuracy variation', '',
                *markdown_table(MULTIDIRECTIONAL_HEADER, [
                    [mode, p.pose, str(v.directions), str(v.n),
                     um_u(v.vap_p, p.multidirectional_u),
                     *(deg_u(value, u) for value, u in zip(
                         (v.vap_a, v.vap_b, v.vap_c), p.multidirectional_angles_u,
                         strict=True))]
                    for mode, p in varied if (v := p.multidirectional) is not None]), '',
                'ISO 9283:1998 §7.2.3: each visit grouped by the direction it was approached '
                'from (the move from the pose commanded before it; within 30° one direction), '
                'vAP the largest distance between two directions\' barycentres (angles: their '
                'mean angles); U from the visits\' covariances.', '']
    distances = [m for m in a.modes if m.distance is not None]
    if distances:
        out += ['## Distance accuracy and repeatability', '',
                *markdown_table(DISTANCE_HEADER, _distance_rows(distances)), '',
                'ISO 9283:1998 §7.3: D the distance between the attained positions of the two '
                'poses in one cycle, AD_p = mean D − commanded D, RD_p = ±3·S_D.', '']
    if mapped(a.modes):
        out += ['## Accuracy map', '', *markdown_table(MAP_HEADER, _map_rows(a.modes)), '',
                f'ISO 9283:1998 AP_p and RP_l over the workspace, for each mode with '
                f'{MAP_LEAST} commanded poses or more (config/accuracy_map.yaml: a grid over a '
                f'box); each pose\'s figures with U are in the per-pose table and '
                f'`summary.json`, and the plot `accuracy_map.png` shows them against each '
                f'axis.', '']
    stabilised = _stabilisation_rows(a.modes)
    if stabilised:
        out += ['## Pose stabilisation time and overshoot', '',
                *markdown_table(STABILISATION_HEADER, stabilised), '',
                f'ISO 9283:1998 §7.4, §7.5 from the tracker\'s readings of each visit, with a '
                f'limit band of {um(s.stabilisation.band)} µm about the attained position: t '
                'from the first entry into the band until the readings stay in it, OV how far '
                'the position went past the attained one in the direction of approach; U '
                '(k = 2) of the means from the readings\' covariances and their spacing '
                '(unresolved: the position moved more than the band between two readings, no U '
                'stated; docs/howto/verdicts.md).', '']
    paths = _path_rows(a.modes)
    if paths:
        out += ['## Path accuracy and repeatability', '',
                *markdown_table(PATH_HEADER, paths), '',
                'ISO 9283:1998 §8.2 of each commanded straight-line path (from the pose '
                'visited before): the attained path\'s points in the planes normal to it at '
                '10 %, 20 % … 90 % of its length (where the tracker\'s readings first crossed '
                'each; planes some cycle did not cross are left out), AT_p the largest '
                'distance of a plane\'s barycentre from the commanded point, RT_l the '
                'largest l̄ + 3·S_l about it; U (k = 2) from the readings\' covariances, for '
                'all planes together (positioning_cell.accuracy.path). §8.6 between the planes '
                'within the plan\'s cruise: v_c the commanded speed (the positioner\'s motion '
                'limits in the cell configuration), AV the mean attained speed\'s departure '
                'from it, RV three standard deviations of the cycles\' means, FV the largest '
                'range of speed within a cycle, all in % of v_c (n/a: no two planes within '
                'the cruise; positioning_cell.accuracy.path_velocity). §9: t_pos the '
                'positioning time, from the move\'s start to the final entry into the '
                'stabilisation band, mean over the cycles (at the configured motion limits: '
                'the positioner\'s fastest; positioning_cell.accuracy.positioning_time).', '']
    drifted = _drift_rows(a.modes)
    if drifted:
        out += ['## Drift of pose characteristics', '',
                *markdown_table(DRIFT_HEADER, drifted), '',
                'ISO 9283:1998 §7.6: dAP = |AP(end) − AP(start)|, dRP = |RP(end) − RP(start)|, '
                "the start and the end the first and the last third of the pose's visits "
                '(n each, T s apart: the mean times of the two); U (k = 2) from the two '
                "epochs' (positioning_cell.accuracy.drift).", '']
    if a.truth_modes:
        out += ['## Simulation truth', '', 'The true platform pose against the target (what '
                'the tracker measures, without its error):', '',
                *markdown_table(COMPARISON_HEADER, comparison_rows(a.truth_modes)), '',
                'The tracker against the truth (measured minus true pose):', '',
                _tracker_line('whole run', a.tracker),
                *(_tracker_line(m.mode, m.tracker) for m in a.modes), '']
    if a.budgets:
        out += ['## Error budget', '', 'What the true position error of each mode\'s settled '
                'visits is made of (RMS over the visits, µm; in brackets the share of the '
                'squared truth error; "—": does not reach the platform in that mode). '
                'Formulas: positioning_cell.analysis.error_budget.', '',
                *markdown_table(BUDGET_HEADER, [_budget_row(b) for b in a.budgets]), '',
                *(f'- {b.mode}: {note}' for b in a.budgets for note in b.notes),
                *(f'- {c.name}: {c.note}' for c in a.budgets[0].contributions
                  if c.rms is None and c.note.startswith('not recorded')), '']
    for test in a.axis_tests:
        out += [f'## Axis test (ISO 230-2), run {test.run}', '',
                'Each actuator driven through its targets in both directions (config/'
                'axis_test.yaml); x = actual − commanded, the actual position from the '
                'tracker (inverse kinematics of the averaged measured pose) and, in '
                'simulation, from the truth (judging only). ISO 230-2:2014 figures: A '
                'accuracy, R repeatability, B reversal, E systematic deviation (over the '
                'means of both directions), M range of the bidirectional means.', '',
                *test.markdown(level=3)]
    if a.compliance:
        out += ['## Static compliance (ISO 9283 §10)', '', 'The load rig pushed the platform '
                'origin along each direction in equal steps while the drives held the pose; '
                'the compliance is the slope of the averaged tracker position against the '
                'load (its magnitude, and its part along the load), U (k = 2) from the '
                'readings\' noise and the rig\'s stated accuracy '
                '(positioning_cell.accuracy.compliance). "Off the line": the largest distance '
                'of a step from the fitted line.', '', *compliance_table(a.compliance), '']
    monitor, counts = a.monitor['verdicts'], a.monitor['decisions']
    rule = a.monitor['tolerances']['decision_rule']
    out += ['## Monitor', '', f'Replaying the bag through the accuracy monitor\'s rules gives '
            f'{monitor["ok"] + monitor["error"]} verdicts: {monitor["ok"]} within tolerance, '
            f'{monitor["error"]} out of tolerance as measured. Accounting for each '
            f'measurement\'s expanded uncertainty U (k = 2, rule {rule}): '
            f'{counts["conforms"]} conform, {counts["indeterminate"]} indeterminate (within '
            f'U of a tolerance), {counts["does_not_conform"]} do not conform (the JSON '
            f'summary holds the monitor\'s report).', '']
    if plots:
        out += ['## Plots', '', *(f'![{p.stem}]({p.name})' for p in plots), '']
    return '\n'.join(out)


def write_report(analysis: RunAnalysis, out_dir: Path, plots: Sequence[Path] = ()
                 ) -> tuple[Path, Path]:
    """Write ``report.md`` and ``summary.json`` into ``out_dir`` (created); their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md = out_dir / REPORT_FILE
    md.write_text(markdown(analysis, plots), encoding='utf-8')
    js = out_dir / SUMMARY_FILE
    doc = {**analysis.to_dict(), 'plots': [p.name for p in plots]}
    js.write_text(json.dumps(doc), encoding='utf-8')  # compact: the C encoder
    return md, js
