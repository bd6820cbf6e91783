"""The acceptance record of a run (issue 25): every ISO 9283:1998 characteristic the run
measured, per compensation mode and commanded pose, with its expanded uncertainty U (k = 2)
and the decision against its acceptance limit (ISO 14253-1:2017 by default: conforms, does
not conform, indeterminate; simple acceptance selectable), the clause of the standard for
each; the characteristics of the standard the run did not measure, named; and the conditions
the figures hold under (the run's span, the machine and its payload as the cell
configuration given to the analysis states them, the calibration in force, the tracker's
locations, the air temperature the cell's sensor read, the decision rule). Written beside the
report as ``acceptance.md`` and ``acceptance.json``.

The figures are those of the report (:mod:`positioning_cell.analysis.summary`): AP_p, AP_a..c
(§7.2.1), RP_l, RP_a..c (§7.2.2), vAP_p, vAP_a..c (§7.2.3), AD_p, RD_p (§7.3), the pose
stabilisation time (§7.4) and overshoot (§7.5), the drifts dAP_p, dAP_a..c, dRP_l, dRP_a..c
(§7.6, of a pose visited often enough), the path accuracy and repeatability AT_p, RT_l
(§8.2, of each commanded path), the path velocity accuracy, repeatability and fluctuation
AV, RV, FV (§8.6, of a path whose plan cruises between two of its planes), the positioning
time of each path (§9, :mod:`positioning_cell.accuracy.positioning_time`), the static
compliance of each load direction (§10, of a run with a compliance test: a property of the
machine, which enters the decision of every mode), each with its U
(:mod:`positioning_cell.accuracy.figure_uncertainty`, :mod:`positioning_cell.accuracy.compliance`,
:mod:`positioning_cell.accuracy.stabilisation`, :mod:`positioning_cell.accuracy.drift`,
:mod:`positioning_cell.accuracy.path`, :mod:`positioning_cell.accuracy.path_velocity`). A
signed figure (AP_a, AD_p) is judged by its magnitude; a figure whose U is unknown decides
nothing under ISO 14253-1 (indeterminate, as a verdict:
:func:`positioning_cell.accuracy.verdicts.decide`). A mode conforms when every
characteristic it measured conforms, does not when one does not, and is indeterminate
otherwise; the record says as well that the standard's other characteristics were not
measured, so that it is never read as a complete acceptance when it is not.

The limits are the ``acceptance:`` block of the run's program file
(:meth:`AcceptanceLimits.from_program`; config/acceptance.yaml), else the defaults here."""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from positioning_cell.accuracy.decisions import Decision, DecisionRule
from positioning_cell.accuracy.drift import FIGURES as DRIFT_FIGURES
from positioning_cell.accuracy.drift import LEAST_VISITS as DRIFT_LEAST_VISITS
from positioning_cell.accuracy.path import PATH_LEAST
from positioning_cell.accuracy.verdicts import decide
from positioning_cell.analysis.compliance_test import CLAUSE
from positioning_cell.analysis.context import AirTemperature
from positioning_cell.analysis.program import Program
from positioning_cell.analysis.summary import (
    DISTANCE_POSES,
    ModeSummary,
    PoseSummary,
    RunAnalysis,
)
from positioning_cell.analysis.tables import markdown_table
from positioning_cell.config import load_parameter_file
from positioning_cell.errors import ConfigError
from positioning_cell.mechanics.statics import Payload
from positioning_cell.motion.settings import machine_settings
from positioning_cell.parameters import check_fields, parse_block, setting

ACCEPTANCE_FILE = 'acceptance.md'
ACCEPTANCE_JSON = 'acceptance.json'

#: The program file's block that holds the limits.
BLOCK = 'acceptance'


@dataclass(frozen=True)
class AcceptanceLimits:
    """The acceptance limits of the ISO 9283 characteristics (upper limits on each figure's
    magnitude; SI: m, rad, s) and the decision rule. The defaults suit the cell's 50 µm /
    0.01° pose tolerance: what a buyer of a precision positioner writes into its
    specification, to be set to the purchase's own."""

    ap_p: float = setting(50e-6, 'pose accuracy AP_p (ISO 9283 7.2.1)', 'm', low=0.0,
                          low_open=True, high=0.01)
    ap_angle: float = setting(math.radians(0.01), 'pose accuracy AP_a, AP_b, AP_c, each '
                              '(7.2.1)', 'rad', low=0.0, low_open=True, high=0.1)
    rp_l: float = setting(20e-6, 'pose repeatability RP_l (7.2.2)', 'm', low=0.0,
                          low_open=True, high=0.01)
    rp_angle: float = setting(math.radians(0.005), 'pose repeatability RP_a, RP_b, RP_c, '
                              'each (7.2.2)', 'rad', low=0.0, low_open=True, high=0.1)
    vap_p: float = setting(30e-6, 'multi-directional pose accuracy variation vAP_p (7.2.3)',
                           'm', low=0.0, low_open=True, high=0.01)
    vap_angle: float = setting(math.radians(0.01), 'multi-directional variation vAP_a, '
                               'vAP_b, vAP_c, each (7.2.3)', 'rad', low=0.0, low_open=True,
                               high=0.1)
    ad_p: float = setting(50e-6, 'distance accuracy AD_p (7.3.1)', 'm', low=0.0,
                          low_open=True, high=0.01)
    rd_p: float = setting(20e-6, 'distance repeatability RD_p (7.3.2)', 'm', low=0.0,
                          low_open=True, high=0.01)
    stabilisation_time: float = setting(2.0, 'pose stabilisation time, mean over the cycles '
                                        '(7.4)', 's', low=0.0, low_open=True, high=60.0)
    overshoot: float = setting(50e-6, 'pose overshoot, mean over the cycles (7.5)', 'm',
                               low=0.0, low_open=True, high=0.01)
    dap_p: float = setting(20e-6, 'drift of pose accuracy dAP_p (7.6)', 'm', low=0.0,
                           low_open=True, high=0.01)
    dap_angle: float = setting(math.radians(0.005), 'drift of pose accuracy dAP_a, dAP_b, '
                               'dAP_c, each (7.6)', 'rad', low=0.0, low_open=True, high=0.1)
    drp_l: float = setting(10e-6, 'drift of pose repeatability dRP_l (7.6)', 'm', low=0.0,
                           low_open=True, high=0.01)
    drp_angle: float = setting(math.radians(0.0025), 'drift of pose repeatability dRP_a, '
                               'dRP_b, dRP_c, each (7.6)', 'rad', low=0.0, low_open=True,
                               high=0.1)
    at_p: float = setting(50e-6, 'path accuracy AT_p (8.2)', 'm', low=0.0, low_open=True,
                          high=0.01)
    rt_l: float = setting(20e-6, 'path repeatability RT_l (8.2)', 'm', low=0.0,
                          low_open=True, high=0.01)
    av: float = setting(0.05, 'path velocity accuracy AV, share of the commanded velocity '
                        '(8.6)', '1', low=0.0, low_open=True, high=1.0)
    rv: float = setting(0.05, 'path velocity repeatability RV, share of the commanded '
                        'velocity (8.6)', '1', low=0.0, low_open=True, high=1.0)
    fv: float = setting(0.10, 'path velocity fluctuation FV, share of the commanded velocity '
                        '(8.6)', '1', low=0.0, low_open=True, high=1.0)
    positioning_time: float = setting(4.0, 'positioning time of each path, mean over its '
                                      'cycles (9)', 's', low=0.0, low_open=True, high=600.0)
    compliance: float = setting(1.5e-6, 'static compliance, each load direction (10)', 'm/N',
                                low=0.0, low_open=True, high=1e-3)
    decision_rule: str = setting(DecisionRule.ISO_14253_1.value, 'how a figure\'s U enters '
                                 'its decision: iso_14253_1 (guard bands of U) or '
                                 'simple_acceptance (U ignored)',
                                 choices=tuple(r.value for r in DecisionRule))

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_program(cls, path: str | Path | None) -> AcceptanceLimits:
        """The limits of the ``acceptance:`` block of the program file at ``path`` (None, or
        a file without the block: the defaults). ConfigError naming the key for a bad
        block."""
        return cls() if path is None else parse_block(cls, path, BLOCK)


@dataclass(frozen=True)
class Characteristic:
    """One figure of the record: of compensation ``mode`` and ``subject`` (a pose, or the
    pair of a distance), ISO 9283 ``name`` and ``clause``; its ``value`` as judged (a
    magnitude), its expanded uncertainty U (NaN: unknown) and ``limit`` in ``unit`` (SI),
    and the ``decision`` the rule drew."""

    mode: str
    subject: str
    name: str
    clause: str
    value: float
    uncertainty: float
    limit: float
    unit: str
    decision: Decision

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; NaN as null; the decision as its words)."""
        out = asdict(self)
        out['decision'] = self.decision.value
        for key in ('value', 'uncertainty', 'limit'):
            out[key] = out[key] if math.isfinite(out[key]) else None
        return out


#: The drift (clause, what): measured by a run that visits a pose often enough.
DRIFT = ('7.6', f'drift of pose accuracy and repeatability dAP, dRP (a pose visited at least '
                f'{DRIFT_LEAST_VISITS} times in a mode)')

#: The path figures (clause, what): measured by a run whose moves the tracker read.
PATH = ('8.2', f'path accuracy and repeatability AT, RT (a move of at least '
               f'{PATH_LEAST * 1e3:.0f} mm whose readings crossed its normal planes)')

#: The path velocity figures (clause, what): measured along a path that cruises between two
#: of its planes.
VELOCITY = ('8.6', 'path velocity characteristics AV, RV, FV (a path whose plan cruises '
                   'between two of its normal planes)')

#: The positioning time (clause, what): measured along a path whose visits stabilised.
POSITIONING = ('9', 'positioning time (a path whose readings entered the stabilisation band '
                    'and stayed)')

#: The static compliance (clause, what): measured by a run whose program has a compliance
#: test.
COMPLIANCE = (CLAUSE, 'static compliance (a program with a compliance: block: load steps '
                      'along each direction)')

#: The mode of a characteristic of the machine itself (the static compliance): it enters the
#: decision of every compensation mode.
MACHINE = 'machine'


def program_gaps(program: Program, given: Collection[str]) -> list[str]:
    """What ``program`` cannot measure of the characteristics whose limits ``given`` (the
    keys its ``acceptance:`` block sets) names, one sentence each with the clause: the
    repeatabilities need two cycles; vAP a pose approached from two other poses; AD and RD
    the distance pair's poses; the drift a pose visited :data:`DRIFT_LEAST_VISITS` times a
    mode; the path figures and the positioning time a move of :data:`PATH_LEAST` or more
    between two poses; the static compliance a compliance: block."""
    order = program.order
    gaps = []
    repeatabilities = {'rp_l': '7.2.2', 'rp_angle': '7.2.2', 'rd_p': '7.3.2', 'rt_l': '8.2',
                       'rv': '8.6'}
    needs_cycles = sorted(set(given) & set(repeatabilities))
    if needs_cycles and program.cycles < 2:
        clauses = ', '.join(sorted({repeatabilities[k] for k in needs_cycles}))
        gaps.append(f'{", ".join(needs_cycles)} (ISO 9283 {clauses}): a repeatability needs '
                    f'at least 2 cycles, the program has {program.cycles}')
    before = {k: {order[i - 1] for i in range(len(order)) if order[i] == k
                  and order[i - 1] != k} for k in set(order)}
    if {'vap_p', 'vap_angle'} & set(given) and max(map(len, before.values())) < 2:
        gaps.append('vap_p, vap_angle (ISO 9283 7.2.3): no pose is approached from two other '
                    'poses (a sequence such as config/acceptance.yaml\'s)')
    if {'ad_p', 'rd_p'} & set(given) and not set(DISTANCE_POSES) <= set(program.names):
        gaps.append(f'ad_p, rd_p (ISO 9283 7.3): the program lacks '
                    f'{" and ".join(p for p in DISTANCE_POSES if p not in program.names)}, '
                    'the distance pair')
    most = program.cycles * max(order.count(k) for k in set(order))
    if {'dap_p', 'dap_angle', 'drp_l', 'drp_angle'} & set(given) and most < DRIFT_LEAST_VISITS:
        gaps.append(f'dap_p, dap_angle, drp_l, drp_angle (ISO 9283 7.6): a drift needs a pose '
                    f'visited {DRIFT_LEAST_VISITS} times a mode, the program visits one at most '
                    f'{most} times')
    steps = [float(np.linalg.norm(program.position[order[i]] - program.position[order[i - 1]]))
             for i in range(len(order))]
    if 'compliance' in given and program.compliance is None:
        gaps.append('compliance (ISO 9283 10): the program has no compliance: block, no load '
                    'steps to measure it')
    along = {'at_p', 'rt_l', 'av', 'rv', 'fv', 'positioning_time'} & set(given)
    if along and max(steps) < PATH_LEAST:
        gaps.append(f'{", ".join(sorted(along))} (ISO 9283 8.2, 8.6, 9): no move between two '
                    f'poses is {PATH_LEAST * 1e3:.0f} mm or longer')
    return gaps


def check_program(path: str | Path, program: Program) -> None:
    """ConfigError naming each characteristic the ``acceptance:`` block of the program file
    at ``path`` sets a limit for and the program cannot measure (:func:`program_gaps`),
    before anything moves; nothing without the block."""
    block = load_parameter_file(path).get(BLOCK) or {}
    gaps = program_gaps(program, list(block) if isinstance(block, Mapping) else [])
    if gaps:
        raise ConfigError(f'{path}: the acceptance: block judges what the program cannot '
                          'measure: ' + '; '.join(gaps))


def not_measured(found: Sequence[Characteristic]) -> tuple[tuple[str, str], ...]:
    """The characteristics of the standard that apply and that ``found`` lacks (clause,
    what): the drift, the path and the path velocity figures when no pose or path gave
    them, the positioning time when no path's visits stabilised, and the static compliance
    when the run had no compliance test."""
    clauses = {c.clause for c in found}
    return tuple(c for c in (DRIFT, PATH, VELOCITY, POSITIONING, COMPLIANCE)
                 if c[0] not in clauses)


def characteristics(analysis: RunAnalysis, limits: AcceptanceLimits
                    ) -> tuple[Characteristic, ...]:
    """Every characteristic the run measured (module docstring), mode by mode in the
    analysis' order, pose by pose, then the mode's distance pair and its paths; then the
    machine's (:data:`MACHINE`): its static compliance."""
    rule = DecisionRule(limits.decision_rule)

    def judged(mode: str, subject: str, name: str, clause: str, value: float | None,
               u: float, limit: float, unit: str) -> list[Characteristic]:
        if value is None or not math.isfinite(value):
            return []  # not defined for this run (RP of a single visit, no approach)
        magnitude = abs(float(value))
        return [Characteristic(mode, subject, name, clause, magnitude, float(u), limit, unit,
                               decide(magnitude, float(u), limit, rule))]

    out: list[Characteristic] = []
    for m in analysis.modes:
        for p in m.poses:
            out += _pose_characteristics(m, p, limits, judged)
        if m.distance is not None:
            pair = ' - '.join(m.distance.poses)
            f, u = m.distance.figures, m.distance.uncertainty
            out += judged(m.mode, pair, 'AD_p', '7.3.1', f.ad_p, u.ad_p, limits.ad_p, 'm')
            out += judged(m.mode, pair, 'RD_p', '7.3.2', f.rd_p, u.rd_p, limits.rd_p, 'm')
        for path in m.paths:
            t = path.figures
            out += judged(m.mode, path.name, 'AT_p', PATH[0], t.at_p, t.u_at_p, limits.at_p,
                          'm')
            out += judged(m.mode, path.name, 'RT_l', PATH[0], t.rt_l, t.u_rt_l, limits.rt_l,
                          'm')
            if (t_pos := path.positioning) is not None:
                out += judged(m.mode, path.name, 't_pos', POSITIONING[0], t_pos.mean, t_pos.u,
                              limits.positioning_time, 's')
            if (v := path.velocity) is not None:
                for name in ('av', 'rv', 'fv'):
                    out += judged(m.mode, path.name, name.upper(), VELOCITY[0],
                                  getattr(v, name), getattr(v, f'u_{name}'),
                                  getattr(limits, name), '1')
    for r in analysis.compliance:
        out += judged(MACHINE, f'{r.pose} {r.direction}', 'compliance', CLAUSE,
                      r.figures.compliance, r.figures.u_compliance, limits.compliance, 'm/N')
    return tuple(out)


def _pose_characteristics(m: ModeSummary, p: PoseSummary, limits: AcceptanceLimits,
                          judged: Any) -> list[Characteristic]:
    """The characteristics of one commanded pose."""
    f, u, o = p.figures, p.uncertainty, p.orientation_uncertainty
    out: list[Characteristic] = judged(m.mode, p.pose, 'AP_p', '7.2.1', f.ap_p, u.ap_p,
                                       limits.ap_p, 'm')
    for axis in 'abc':
        out += judged(m.mode, p.pose, f'AP_{axis}', '7.2.1', getattr(f, f'ap_{axis}'),
                      getattr(o, f'ap_{axis}'), limits.ap_angle, 'rad')
    out += judged(m.mode, p.pose, 'RP_l', '7.2.2', f.rp_l, u.rp_l, limits.rp_l, 'm')
    for axis in 'abc':
        out += judged(m.mode, p.pose, f'RP_{axis}', '7.2.2', getattr(f, f'rp_{axis}'),
                      getattr(o, f'rp_{axis}'), limits.rp_angle, 'rad')
    if p.multidirectional is not None:
        v = p.multidirectional
        out += judged(m.mode, p.pose, 'vAP_p', '7.2.3', v.vap_p, p.multidirectional_u,
                      limits.vap_p, 'm')
        for axis, u_angle in zip('abc', p.multidirectional_angles_u, strict=True):
            out += judged(m.mode, p.pose, f'vAP_{axis}', '7.2.3', getattr(v, f'vap_{axis}'),
                          u_angle, limits.vap_angle, 'rad')
    if p.stabilisation is not None:
        s = p.stabilisation
        out += judged(m.mode, p.pose, 't_stab', '7.4', s.time_mean, s.time_u,
                      limits.stabilisation_time, 's')
        out += judged(m.mode, p.pose, 'overshoot', '7.5', s.overshoot_mean, s.overshoot_u,
                      limits.overshoot, 'm')
    if (d := p.drift) is not None:
        for name in DRIFT_FIGURES:
            limit = getattr(limits, f'd{name}' if name in ('ap_p', 'rp_l')
                            else f'd{name[:2]}_angle')
            out += judged(m.mode, p.pose, f'd{name[:2].upper()}{name[2:]}', DRIFT[0],
                          *d.figure(name), limit, 'm' if name in ('ap_p', 'rp_l') else 'rad')
    return out


def of_mode(found: Sequence[Characteristic], mode: str) -> list[Characteristic]:
    """The characteristics that decide ``mode``: its own and the machine's."""
    return [c for c in found if c.mode in (mode, MACHINE)]


def overall(found: Sequence[Characteristic]) -> Decision:
    """The decision on a set of characteristics: conforms when every one does, does not
    conform when one does not, else (or with none) indeterminate."""
    decided = {c.decision for c in found}
    if Decision.DOES_NOT_CONFORM in decided:
        return Decision.DOES_NOT_CONFORM
    return Decision.CONFORMS if decided == {Decision.CONFORMS} else Decision.INDETERMINATE


@dataclass(frozen=True)
class AcceptanceRecord:
    """The record of one run: its characteristics, the decision per mode, the program
    ``cycles`` each mode ran, the limits and the conditions (:func:`acceptance_record`)."""

    bag: str
    start: float
    end: float
    limits: AcceptanceLimits
    characteristics: tuple[Characteristic, ...]
    modes: dict[str, Decision]
    cycles: dict[str, int]
    calibrations: tuple[str, ...]
    registrations: tuple[str, ...]
    #: The cell configuration the analysis was given (the machine, the payload) and the
    #: payload it configures (None: no configuration given); not recorded in the bag.
    config: str | None = None
    payload: Payload | None = None
    #: The air temperature the cell's sensor read over the run (None: not recorded).
    air_temperature: AirTemperature | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return {'bag': self.bag, 'start': self.start, 'end': self.end,
                'conditions': {
                    'config': self.config,
                    'payload': None if self.payload is None else asdict(self.payload),
                    'air_temperature': None if self.air_temperature is None
                    else asdict(self.air_temperature)},
                'limits': asdict(self.limits),
                'modes': {k: v.value for k, v in self.modes.items()}, 'cycles': self.cycles,
                'calibrations': list(self.calibrations),
                'registrations': list(self.registrations),
                'characteristics': [c.to_dict() for c in self.characteristics],
                'not_measured': [{'clause': c, 'characteristic': w}
                                 for c, w in not_measured(self.characteristics)]}


def acceptance_record(analysis: RunAnalysis, limits: AcceptanceLimits,
                      config: str | Path | None = None) -> AcceptanceRecord:
    """The :class:`AcceptanceRecord` of an analysed run against ``limits``; the machine and
    its payload those of the cell parameter file ``config`` (None: not stated)."""
    found = characteristics(analysis, limits)
    context = analysis.context
    return AcceptanceRecord(
        str(analysis.bag), context.start, context.end, limits, found,
        {m.mode: overall(of_mode(found, m.mode)) for m in analysis.modes},
        {m.mode: max((v.cycle or 0 for v in analysis.replay.visits if v.mode == m.mode),
                     default=0) for m in analysis.modes},
        tuple(f'{_utc(c.time)}: {c.file or "none (the nominal machine)"}'
              for c in context.calibrations),
        tuple(f'{_utc(r.time)}: location {r.locations}, residual RMS {r.residual_rms_um:.1f} '
              f'µm (max {r.residual_max_um:.1f}), σ '
              f'{", ".join(f"{s:.1f}" for s in r.sigma_position_um)} µm, '
              f'{", ".join(f"{s:.1f}" for s in r.sigma_rotation_urad)} µrad'
              for r in context.registrations),
        None if config is None else str(config),
        None if config is None else machine_settings(config).payload,
        context.air_temperature)


def _utc(stamp: float) -> str:
    """A stamp (s since the epoch) as UTC ISO 8601 to the second ('n/a' if not finite)."""
    if not math.isfinite(stamp):
        return 'n/a'
    return datetime.fromtimestamp(stamp, UTC).strftime('%Y-%m-%d %H:%M:%S UTC')


#: How each unit is printed: the factor from SI and the unit's name.
UNITS = {'m': (1e6, 'µm', '.1f'), 'rad': (180.0 / math.pi, '°', '.4f'), 's': (1.0, 's', '.2f'),
         '1': (100.0, '%', '.2f'), 'm/N': (1e6, 'µm/N', '.3f')}


def _shown(value: float, unit: str) -> str:
    factor, _, spec = UNITS[unit]
    return f'{value * factor:{spec}}' if math.isfinite(value) else '?'


def markdown(record: AcceptanceRecord) -> str:
    """The record for people (µm, degrees, s)."""
    rule = DecisionRule(record.limits.decision_rule)
    lines = ['# Acceptance record: ISO 9283:1998 pose characteristics', '',
             f'- Recording: `{record.bag}`, {_utc(record.start)} to {_utc(record.end)}',
             f'- Decision rule: {rule.value} (ISO 14253-1:2017 guard bands of U, k = 2; a '
             f'figure whose U is unknown is indeterminate)' if rule is DecisionRule.ISO_14253_1
             else f'- Decision rule: {rule.value} (U not used)']
    lines.append('- Calibration in force: ' + ('; '.join(record.calibrations) or 'not recorded'))
    lines.append('- Tracker located: ' + ('; '.join(record.registrations) or 'not recorded'))
    lines += _conditions(record)
    lines += ['', '## Decision per compensation mode', '']
    lines += markdown_table(('mode', 'cycles', 'characteristics', 'C/I/N', 'decision'), [
        [mode, str(record.cycles[mode]), str(len(of_mode(record.characteristics, mode))),
         '/'.join(str(sum(c.decision is d for c in of_mode(record.characteristics, mode)))
                  for d in (Decision.CONFORMS, Decision.INDETERMINATE,
                            Decision.DOES_NOT_CONFORM)),
         decision.value.upper()] for mode, decision in record.modes.items()])
    lines += ['', 'C/I/N: characteristics that conform, are indeterminate, do not conform. The '
              'decision covers the characteristics below only (those of mode '
              f'"{MACHINE}", the machine\'s own, in every mode\'s); the standard\'s others '
              'were not measured (last section).', '', '## Characteristics', '']
    lines += markdown_table(
        ('mode', 'pose', 'characteristic', 'ISO 9283', 'value ± U', 'limit', 'unit',
         'decision'),
        [[c.mode, c.subject, c.name, f'§{c.clause}',
          f'{_shown(c.value, c.unit)} ± {_shown(c.uncertainty, c.unit)}',
          _shown(c.limit, c.unit), UNITS[c.unit][1], c.decision.value]
         for c in record.characteristics])
    lines += ['', '## Not measured by this run', '']
    lines += [f'- §{clause}: {what}' for clause, what in not_measured(record.characteristics)
              ] or ['- none: every characteristic of the standard that applies to the '
                    'positioner has a figure above']
    return '\n'.join(lines) + '\n'


def _conditions(record: AcceptanceRecord) -> list[str]:
    """The record's lines on the machine, its payload and the air temperature."""
    p, air = record.payload, record.air_temperature
    if record.config is None or p is None:
        lines = ['- Machine and payload: no cell configuration given to the analysis']
    else:
        force, moment = p.external_wrench[:3], p.external_wrench[3:]
        lines = [f'- Machine: the positioner of `{record.config}` (its mechanism: block), '
                 'calibrated as below',
                 f'- Payload (configured in `{record.config}`, not recorded in the bag): '
                 f'{p.mass:g} kg, centre of gravity '
                 f'({", ".join(f"{v:g}" for v in p.centre_of_gravity)}) m in the platform '
                 f'frame; external force ({", ".join(f"{v:g}" for v in force)}) N, moment '
                 f'({", ".join(f"{v:g}" for v in moment)}) N·m']
    lines.append('- Air temperature: not recorded' if air is None else
                 f'- Air temperature (the cell\'s sensor): {air.low:.2f} to {air.high:.2f} °C, '
                 f'mean {air.mean:.2f} °C over {air.readings} readings')
    return lines


def write_acceptance(analysis: RunAnalysis, out_dir: Path, limits: AcceptanceLimits,
                     config: str | Path | None = None) -> tuple[Path, Path]:
    """Write ``acceptance.md`` and ``acceptance.json`` into ``out_dir`` (the machine and
    payload of ``config``: :func:`acceptance_record`); their paths."""
    record = acceptance_record(analysis, limits, config)
    out_dir.mkdir(parents=True, exist_ok=True)
    text, doc = out_dir / ACCEPTANCE_FILE, out_dir / ACCEPTANCE_JSON
    text.write_text(markdown(record))
    doc.write_text(json.dumps(record.to_dict(), indent=1, allow_nan=False) + '\n')
    return text, doc


__all__ = ['ACCEPTANCE_FILE', 'ACCEPTANCE_JSON', 'COMPLIANCE', 'DRIFT', 'MACHINE',
           'PATH', 'POSITIONING', 'VELOCITY',
           'AcceptanceLimits',
           'AcceptanceRecord', 'Characteristic', 'acceptance_record', 'characteristics',
           'check_program', 'markdown', 'not_measured', 'of_mode', 'overall', 'program_gaps',
           'write_acceptance']
