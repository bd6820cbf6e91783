"""The acceptance record (positioning_cell.analysis.acceptance): every characteristic the
report computed, with its U, limit, clause and the decision the rule draws; the decision per
mode; the limits from a program file; what the run did not measure; the files analyze
writes."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from positioning_cell.accuracy import MonitorSettings
from positioning_cell.accuracy.decisions import Decision
from positioning_cell.accuracy.drift import FIGURES as DRIFT_FIGURES
from positioning_cell.accuracy.drift import LEAST_VISITS
from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.acceptance import (
    COMPLIANCE,
    DRIFT,
    PATH,
    POSITIONING,
    VELOCITY,
    AcceptanceLimits,
    Characteristic,
    acceptance_record,
    characteristics,
    markdown,
    not_measured,
    overall,
)
from positioning_cell.analysis.context import AirTemperature, ContextCollector
from positioning_cell.config import config_path
from positioning_cell.errors import ConfigError
from positioning_cell.names import STATUS_MEASUREMENT
from positioning_cell.parameters import parse
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag
from positioning_cell.tools.analyze_bag import analyze

SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))
POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                      [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = synthetic_run(POSITIONS, np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)), cycles=3,
                        dwell_time=1.5, seed=3)
    path = tmp_path_factory.mktemp('acceptance') / 'bag'
    write_run_bag(path, run)
    return path


def test_each_characteristic_is_the_reports_figure_with_its_u_and_decision(bag: Path) -> None:
    """The record's figures are the summary's, by name and clause: AP_p and RP_l with the
    report's U, each angle's magnitude, AD_p and RD_p of the distance pair, the
    stabilisation figures' means; each decided against its limit by ISO 14253-1 (conforms
    within limit − U, does not beyond limit + U, else indeterminate)."""
    analysis = analyse_bag(bag, SETTINGS)
    limits = AcceptanceLimits()
    found = characteristics(analysis, limits)
    by = {(c.mode, c.subject, c.name): c for c in found}
    assert {m.mode for m in analysis.modes} == {c.mode for c in found} == {
        'none', 'model', 'measured'}
    for m in analysis.modes:
        for p in m.poses:
            ap = by[(m.mode, p.pose, 'AP_p')]
            assert (ap.value, ap.uncertainty, ap.clause) == (p.figures.ap_p, p.uncertainty.ap_p,
                                                              '7.2.1')
            rp = by[(m.mode, p.pose, 'RP_l')]
            assert (rp.value, rp.uncertainty, rp.limit) == (p.figures.rp_l, p.uncertainty.rp_l,
                                                             limits.rp_l)
            b = by[(m.mode, p.pose, 'AP_b')]
            assert b.value == abs(p.figures.ap_b) and b.unit == 'rad'
            assert b.uncertainty == p.orientation_uncertainty.ap_b
            assert p.stabilisation is not None
            assert by[(m.mode, p.pose, 't_stab')].value == p.stabilisation.time_mean
        assert m.distance is not None
        ad = by[(m.mode, ' - '.join(m.distance.poses), 'AD_p')]
        assert ad.value == abs(m.distance.figures.ad_p) and ad.clause == '7.3.1'
    for c in found:
        if not math.isfinite(c.uncertainty):
            assert c.decision is Decision.INDETERMINATE
        elif c.value <= c.limit - c.uncertainty:
            assert c.decision is Decision.CONFORMS
        elif c.value > c.limit + c.uncertainty:
            assert c.decision is Decision.DOES_NOT_CONFORM
        else:
            assert c.decision is Decision.INDETERMINATE
    # the synthetic biases: mode none is 450 µm off, the others within 50 µm
    record = acceptance_record(analysis, limits)
    assert record.modes['none'] is Decision.DOES_NOT_CONFORM
    assert by[('none', 'P1', 'AP_p')].decision is Decision.DOES_NOT_CONFORM
    assert by[('measured', 'P1', 'AP_p')].decision is Decision.CONFORMS
    assert record.cycles == {'none': 3, 'model': 3, 'measured': 3}


def test_a_limit_within_u_of_the_figure_is_indeterminate_and_simple_acceptance_decides(
        bag: Path) -> None:
    """The limit of AP_p put just above one pose's figure, closer than its U: indeterminate
    by ISO 14253-1, conforms by simple acceptance (U ignored); just below: does not conform
    by simple acceptance, indeterminate by ISO 14253-1."""
    analysis = analyse_bag(bag, SETTINGS)
    ap = next(c for c in characteristics(analysis, AcceptanceLimits())
              if (c.mode, c.subject, c.name) == ('model', 'P2', 'AP_p'))
    assert ap.uncertainty > 0.0
    for shift, iso, simple in ((0.5, Decision.INDETERMINATE, Decision.CONFORMS),
                               (-0.5, Decision.INDETERMINATE, Decision.DOES_NOT_CONFORM)):
        limit = ap.value + shift * ap.uncertainty
        for rule, expected in (('iso_14253_1', iso), ('simple_acceptance', simple)):
            limits = parse(AcceptanceLimits, {'ap_p': limit, 'decision_rule': rule})
            got = next(c for c in characteristics(analysis, limits)
                       if (c.mode, c.subject, c.name) == ('model', 'P2', 'AP_p'))
            assert got.decision is expected, (shift, rule)


def _characteristic(decision: Decision) -> Characteristic:
    return Characteristic('model', 'P1', 'AP_p', '7.2.1', 1e-5, 1e-6, 5e-5, 'm', decision)


@pytest.mark.parametrize(('decisions', 'expected'), [
    ((Decision.CONFORMS, Decision.CONFORMS), Decision.CONFORMS),
    ((Decision.CONFORMS, Decision.INDETERMINATE), Decision.INDETERMINATE),
    ((Decision.INDETERMINATE, Decision.DOES_NOT_CONFORM), Decision.DOES_NOT_CONFORM),
    ((), Decision.INDETERMINATE),
])
def test_a_mode_conforms_only_when_every_characteristic_does(
        decisions: tuple[Decision, ...], expected: Decision) -> None:
    assert overall([_characteristic(d) for d in decisions]) is expected


def test_the_limits_come_from_the_program_files_block(tmp_path: Path) -> None:
    """config/acceptance.yaml's block (the defaults, written out); a file without the block:
    the defaults; a bad value or key: ConfigError naming it."""
    shipped = AcceptanceLimits.from_program(config_path('acceptance.yaml'))
    defaults = AcceptanceLimits()
    for name in ('ap_p', 'rp_l', 'vap_p', 'ad_p', 'rd_p', 'stabilisation_time', 'overshoot',
                 'dap_p', 'drp_l', 'at_p', 'rt_l', 'av', 'rv', 'fv'):
        assert getattr(shipped, name) == getattr(defaults, name)
    for name in ('ap_angle', 'rp_angle', 'vap_angle', 'dap_angle', 'drp_angle'):
        assert getattr(shipped, name) == pytest.approx(getattr(defaults, name), rel=1e-3)
    assert AcceptanceLimits.from_program(config_path('program.yaml')) == defaults
    assert AcceptanceLimits.from_program(None) == defaults
    bad = tmp_path / 'program.yaml'
    for block, words in (('acceptance: {ap_p: -1.0}', 'ap_p'),
                         ('acceptance: {rp_q: 1.0e-5}', 'rp_q'),
                         ('acceptance: {decision_rule: lenient}', 'decision_rule'),
                         ('acceptance: [1, 2]', 'mapping')):
        bad.write_text(block + '\n')
        with pytest.raises(ConfigError, match=words):
            AcceptanceLimits.from_program(bad)


def test_the_record_names_what_it_did_not_measure_and_writes_no_nan(bag: Path,
                                                                    tmp_path: Path) -> None:
    """analyze writes acceptance.md and acceptance.json beside the report: the decision per
    mode, each characteristic with its clause, the standard's characteristics not measured;
    an unknown U is null in the JSON, '?' in the text."""
    output = analyze(bag, tmp_path / 'out', plots=False,
                     program=config_path('acceptance.yaml'))
    assert output.acceptance == tmp_path / 'out' / 'acceptance.md'
    text = output.acceptance.read_text()
    doc = json.loads((tmp_path / 'out' / 'acceptance.json').read_text())
    assert set(doc['modes']) == {'none', 'model', 'measured'}
    assert doc['modes']['none'] == 'does not conform'
    assert len(doc['characteristics']) == len(characteristics(
        output.analysis, AcceptanceLimits()))
    # three cycles: no pose is visited often enough for a drift; every move has a path
    assert [n['clause'] for n in doc['not_measured']] == [c for c, _ in (DRIFT, COMPLIANCE)]
    for clause, what in (DRIFT, COMPLIANCE):
        assert f'§{clause}: {what}' in text
    assert '| none | P1 | AP_p | §7.2.1 |' in text and 'DOES NOT CONFORM' in text
    # the conditions: the machine and payload of the configuration the analysis was given
    assert f'- Machine: the positioner of `{config_path("cell.yaml")}`' in text
    assert 'not recorded in the bag): 50 kg, centre of gravity (0, 0, 0.1) m' in text
    assert '- Air temperature: not recorded' in text  # no tracker diagnostics in this bag
    assert doc['conditions']['payload']['mass'] == 50.0
    assert doc['conditions']['air_temperature'] is None
    record = acceptance_record(output.analysis, AcceptanceLimits())
    unknown = replace(record, characteristics=(replace(
        record.characteristics[0], uncertainty=math.nan, decision=Decision.INDETERMINATE),))
    assert unknown.to_dict()['characteristics'][0]['uncertainty'] is None
    assert ' ± ? |' in markdown(unknown)
    simple = acceptance_record(output.analysis, parse(AcceptanceLimits,
                                                      {'decision_rule': 'simple_acceptance'}))
    assert 'Decision rule: simple_acceptance (U not used)' in markdown(simple)
    assert 'Decision rule: iso_14253_1' in text and 'unknown is indeterminate' in text


def test_a_pose_visited_often_enough_gets_its_drift_judged_and_reported(
        tmp_path: Path) -> None:
    """Six cycles: every pose of every mode has its eight drift figures (§7.6) in the record,
    each the summary's with its U and judged against its limit; the report shows them and the
    record no longer lists §7.6 as not measured."""
    run = synthetic_run(POSITIONS, np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)), cycles=LEAST_VISITS,
                        dwell_time=1.5, seed=4)
    write_run_bag(tmp_path / 'bag', run)
    output = analyze(tmp_path / 'bag', tmp_path / 'out', plots=False)
    limits = AcceptanceLimits()
    found = [c for c in characteristics(output.analysis, limits) if c.clause == DRIFT[0]]
    poses = [(m, p) for m in output.analysis.modes for p in m.poses]
    assert len(found) == len(DRIFT_FIGURES) * len(poses) > 0
    by = {(c.mode, c.subject, c.name): c for c in found}
    for m, p in poses:
        assert p.drift is not None and p.drift.cycles == LEAST_VISITS // 3
        value, u = p.drift.figure('ap_p')
        c = by[(m.mode, p.pose, 'dAP_p')]
        assert (c.value, c.uncertainty, c.limit) == (value, u, limits.dap_p)
        assert by[(m.mode, p.pose, 'dRP_c')].limit == limits.drp_angle
    doc = json.loads((tmp_path / 'out' / 'acceptance.json').read_text())
    assert DRIFT[0] not in [n['clause'] for n in doc['not_measured']]
    report = output.report.read_text()
    assert '## Drift of pose characteristics' in report
    summary = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    assert summary['modes'][0]['poses'][0]['drift']['first']['n'] == LEAST_VISITS // 3


def test_each_commanded_path_gets_its_path_figures_judged(bag: Path) -> None:
    """Every move between two program poses of one mode is a path (ISO 9283 §8.2): P1 → P2 …
    P5 → P1 in each mode, each with the cycles that moved along it; the first move of a mode
    (planned from where the mode before left the platform) and the run's first move are
    none of them. Each path's AT_p and RT_l are in the record with their U and limits, and
    its AV, RV and FV (§8.6; the synthetic run's moves keep to no plan: AV is far from 0)."""
    analysis = analyse_bag(bag, SETTINGS)
    limits = AcceptanceLimits()
    by = {(c.mode, c.subject, c.name): c for c in characteristics(analysis, limits)
          if c.clause == PATH[0]}
    names = ['P1 → P2', 'P2 → P3', 'P3 → P4', 'P4 → P5', 'P5 → P1']
    for m in analysis.modes:
        assert [p.name for p in m.paths] == names
        assert [p.figures.n for p in m.paths] == [3, 3, 3, 3, 2]  # 3 cycles
        for p in m.paths:
            f = p.figures
            assert f.planes and math.isfinite(f.u_at_p) and math.isfinite(f.u_rt_l)
            at, rt = by[(m.mode, p.name, 'AT_p')], by[(m.mode, p.name, 'RT_l')]
            assert (at.value, at.uncertainty, at.limit) == (f.at_p, f.u_at_p, limits.at_p)
            assert (rt.value, rt.uncertainty, rt.limit) == (f.rt_l, f.u_rt_l, limits.rt_l)
    # the commanded speed: the plan's with the cell configuration's motion limits
    found = characteristics(analysis, limits)
    for m in analysis.modes:
        for p in m.paths:
            v = p.velocity
            assert v is not None and v.commanded == pytest.approx(0.01)  # config/cell.yaml
            by_v = {c.name: c for c in found if c.subject == p.name and c.mode == m.mode
                    and c.clause == VELOCITY[0]}
            assert by_v['AV'].value == pytest.approx(abs(v.av))
            assert (by_v['FV'].uncertainty, by_v['FV'].limit) == (v.u_fv, limits.fv)
    assert {PATH, VELOCITY, POSITIONING}.isdisjoint(not_measured(found))


def test_each_path_gets_its_positioning_time_judged(bag: Path) -> None:
    """ISO 9283 §9: every path's positioning time is the mean over its cycles of each
    visit's time from its segment's start to the final entry into the stabilisation band,
    judged against its limit with U; a path's visits' times are their stabilisation
    records'."""
    analysis = analyse_bag(bag, SETTINGS)
    limits = AcceptanceLimits()
    found = {(c.mode, c.subject): c for c in characteristics(analysis, limits)
             if c.clause == POSITIONING[0]}
    stated = 0
    for m in analysis.modes:
        for p in m.paths:
            t = p.positioning
            assert t is not None and t.cycles == p.figures.n
            assert t.distance == pytest.approx(p.figures.length)
            assert 0.5 < t.mean <= t.longest < 30.0
            assert not t.u <= 0.0  # positive, or NaN: a visit's readings stated none
            stated += math.isfinite(t.u)
            c = found[(m.mode, p.name)]
            assert (c.name, c.value, c.limit, c.unit) == ('t_pos', t.mean,
                                                          limits.positioning_time, 's')
            assert c.uncertainty == t.u or (math.isnan(c.uncertainty) and math.isnan(t.u))
    assert stated >= 5
    visits = [v for v in analysis.replay.visits if v.mode == 'model' and v.pose == 'P3']
    times = [v.stabilisation.positioning_time for v in visits]
    assert all(math.isfinite(x) and x > v.stabilisation.time for x, v in zip(
        times, visits, strict=True))


_PROGRAM = '''program:
  cycles: {cycles}
  modes: [model]
  {sequence}
  poses:
    P1: {{position: [0.000, 0.000, 0.196], orientation: [0.0, 0.0, 0.0, 1.0]}}
    P2: {{position: [0.004, 0.004, 0.200], orientation: [0.0, 0.0, 0.0, 1.0]}}
    P4: {{position: [{p4x}, -0.004, 0.192], orientation: [0.0, 0.0, 0.0, 1.0]}}
acceptance: {{{keys}}}
'''


@pytest.mark.parametrize(('cycles', 'sequence', 'p4x', 'keys', 'clauses'), [
    (1, '', -0.004, 'rp_l: 2.0e-5', ['7.2.2']),
    (2, '', -0.004, 'vap_p: 3.0e-5', ['7.2.3']),
    (2, 'sequence: [P1, P2, P1, P4]', -0.004, 'vap_p: 3.0e-5', []),
    (5, '', -0.004, 'dap_p: 2.0e-5', ['7.6']),
    (6, '', -0.004, 'dap_p: 2.0e-5, drp_angle: 4.0e-5', []),
    (3, 'sequence: [P2, P1, P2, P1]', -0.004, 'drp_l: 1.0e-5', []),  # P2 twice a cycle
    (2, '', -0.004, 'at_p: 5.0e-5, ad_p: 5.0e-5', []),
    (1, '', -0.004, 'rt_l: 2.0e-5, ap_p: 5.0e-5', ['8.2']),
])
def test_an_acceptance_block_the_program_cannot_measure_is_refused_before_motion(
        tmp_path: Path, cycles: int, sequence: str, p4x: float, keys: str,
        clauses: list[str]) -> None:
    """A limit the program cannot give a figure for is named with its clause, before the cell
    starts (run_cell exits with a usage error and makes no run folder); a program whose
    block it can measure, and one without a block, pass."""
    from positioning_cell.analysis.acceptance import check_program, program_gaps
    from positioning_cell.analysis.program import load_program
    from positioning_cell.core.mechanism import Mechanism
    from positioning_cell.tools import cell_run
    from positioning_cell.tools.exits import Exit
    path = tmp_path / 'program.yaml'
    path.write_text(_PROGRAM.format(cycles=cycles, sequence=sequence, p4x=p4x, keys=keys))
    program = load_program(path, Mechanism.default())
    gaps = program_gaps(program, [k.split(':')[0].strip() for k in keys.split(',')])
    assert [g.split('(ISO 9283 ')[1].split(')')[0] for g in gaps] == clauses
    if not clauses:
        check_program(path, program)
        return
    said: list[str] = []
    assert cell_run.run(path, runs_dir=tmp_path / 'runs', say=said.append) == Exit.USAGE
    assert not (tmp_path / 'runs').exists()
    assert 'cannot measure' in said[0] and all(f'ISO 9283 {c}' in said[0] for c in clauses)


def test_the_shipped_programs_pass_their_acceptance_check() -> None:
    from positioning_cell.analysis.acceptance import check_program
    from positioning_cell.analysis.program import load_program
    from positioning_cell.core.mechanism import Mechanism
    for name in ('acceptance.yaml', 'program.yaml', 'accuracy_map.yaml'):
        check_program(config_path(name), load_program(config_path(name), Mechanism.default()))


def test_missing_distance_poses_and_short_moves_are_named(tmp_path: Path) -> None:
    from positioning_cell.analysis.acceptance import program_gaps
    from positioning_cell.analysis.program import load_program
    from positioning_cell.core.mechanism import Mechanism
    path = tmp_path / 'program.yaml'
    path.write_text(_PROGRAM.format(cycles=2, sequence='sequence: [P1]', p4x=-0.004,
                                    keys='').replace('P2:', 'P3:'))
    gaps = program_gaps(load_program(path, Mechanism.default()),
                        ['ad_p', 'at_p', 'positioning_time'])
    assert len(gaps) == 2 and 'lacks P2' in gaps[0] and '1 mm or longer' in gaps[1]
    assert gaps[1].startswith('at_p, positioning_time (ISO 9283 8.2, 8.6, 9)')


def test_the_air_temperature_of_the_run_comes_from_the_trackers_diagnostics() -> None:
    """The tracker simulator's diagnostics carry the air sensor's reading: the record's
    lowest, mean and highest over the run, 'nan' (before the first reading) left out."""
    collector = ContextCollector()
    for stamp, value in enumerate(['nan', '20.5', '20.75', '20.25']):
        status = SimpleNamespace(name=STATUS_MEASUREMENT, values=[
            SimpleNamespace(key='air_temperature_c', value=value)])
        collector.diagnostics(float(stamp), [status])
    air = collector.result(0.0, 4.0).air_temperature
    assert air == AirTemperature(20.25, 20.5, 20.75, 3)
    assert ContextCollector().result(0.0, 1.0).air_temperature is None
