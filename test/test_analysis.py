"""analyze_bag and the analysis library on synthetic bags written with rosbags' writer: the
figures equal the batch functions of positioning_cell.accuracy on the same samples, the report
and plots are written, and bad input (not a bag, missing topics, a truncated file) gives a
clear message and a non-zero exit. No ROS graph."""

from __future__ import annotations

import dataclasses
import gzip
import itertools
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from json_compare import differences

from positioning_cell import accuracy
from positioning_cell.accuracy import Ignored, Monitor, MonitorSettings
from positioning_cell.analysis import analyse_bag, message_batches, replay
from positioning_cell.analysis.program import ProgramStep, load_program
from positioning_cell.analysis.replay import OUTSIDE_PROGRAM
from positioning_cell.analysis.report import markdown
from positioning_cell.analysis.summary import ANALYSED_TOPICS
from positioning_cell.analysis.trace import ErrorTrace
from positioning_cell.bag import BagReader
from positioning_cell.config import config_path
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError
from positioning_cell.metrology.instrument import Registration, averaged_covariance
from positioning_cell.moves.correction import mean_reading
from positioning_cell.names import MEASURED_POSE, TARGET
from positioning_cell.testing.synthetic_run import SyntheticRun, synthetic_run, write_run_bag
from positioning_cell.tools.analyze_bag import analyze, main
from positioning_cell.tools.exits import Exit

SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))
POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                      [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
QUATERNIONS[1] = [0.0, 0.0, math.sin(0.005), math.cos(0.005)]  # one pose turned 0.57° about z


@pytest.fixture(scope='module')
def run() -> SyntheticRun:
    return synthetic_run(POSITIONS, QUATERNIONS, cycles=2, dwell_time=1.5, seed=7)


@pytest.fixture(scope='module')
def bag(run: SyntheticRun, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('bags') / 'run'
    write_run_bag(path, run, joint_state_rate=50.0)
    return path


def _batch(run: SyntheticRun, n: int | None = None) -> accuracy.AccuracyResult:
    return accuracy.analyse(run.time[:n], run.position[:n], run.quaternion[:n], run.target_time,
                            run.target_position, run.target_quaternion, SETTINGS.settle,
                            end_times=run.end_time)


def _numbers(doc: dict[str, object]) -> np.ndarray:
    """The numbers of a to_dict() document in key order (None as NaN)."""
    out: list[float] = []
    for key in sorted(doc):
        value = doc[key]
        out.extend(float(v) for v in value) if isinstance(value, list) else out.append(
            math.nan if value is None else float(value))  # type: ignore[arg-type]
    return np.array(out)


def _same_figures(a: dict[str, object], b: dict[str, object]) -> None:
    assert sorted(a) == sorted(b)
    np.testing.assert_allclose(_numbers(a), _numbers(b), rtol=1e-12, atol=1e-15)


def _same_visit(a: accuracy.Visit, b: accuracy.Visit) -> None:
    assert (a.key, a.cycle, a.samples) == (b.key, b.cycle, b.samples)
    assert a.target_time == pytest.approx(b.target_time, abs=1e-6)  # ns stamps
    assert a.settle_time == pytest.approx(b.settle_time, abs=1e-6)
    np.testing.assert_allclose(a.position, b.position, atol=1e-12)
    np.testing.assert_allclose(a.quaternion, b.quaternion, atol=1e-12)


def test_figures_equal_the_batch_analysis_of_the_same_samples(run: SyntheticRun,
                                                               bag: Path) -> None:
    analysis = analyse_bag(bag, SETTINGS)
    batch = _batch(run)
    visits = analysis.replay.visits
    assert len(visits) == len(batch.visits) == len(run.steps) == 30
    for mine, theirs in zip(visits, batch.visits, strict=True):
        _same_visit(mine.visit, theirs)
    # labels from /cell/program: the step whose move each visit settled
    step_of = {round(t, 3): s for t, s in zip(run.target_time, run.steps, strict=True)}
    for v in visits:
        step = step_of[round(v.visit.target_time, 3)]
        assert (v.mode, v.pose) == (step.mode, step.pose)
    assert [m.mode for m in analysis.modes] == ['none', 'model', 'measured']
    for mode in analysis.modes:
        assert [p.pose for p in mode.poses] == ['P1', 'P2', 'P3', 'P4', 'P5']
        for pose in mode.poses:
            mine = [b for b, v in zip(batch.visits, visits, strict=True)
                    if (v.mode, v.pose) == (mode.mode, pose.pose)]
            expected = accuracy.iso9283(mine[0].commanded_position,
                                        mine[0].commanded_quaternion,
                                        [b.position for b in mine], [b.quaternion for b in mine],
                                        mine[0].key)
            _same_figures(pose.figures.to_dict(), expected.to_dict())
            errors = [accuracy.judge_visit(b, SETTINGS.tolerance) for b in mine]
            d = np.array([e.position_error for e in errors])
            assert pose.extremes.n == 2
            assert pose.extremes.position_error_max == pytest.approx(d.max(), abs=1e-12)
            assert pose.extremes.position_error_rms == pytest.approx(
                np.sqrt((d ** 2).mean()), abs=1e-12)
            assert pose.extremes.within_tolerance == sum(e.ok for e in errors)
    # the whole-run monitor figures, as the live node reports them
    report = analysis.monitor
    assert len(report['measured']['poses']) == len(batch.poses) == 5
    for mine_pose, theirs_pose in zip(report['measured']['poses'], batch.poses, strict=True):
        _same_figures(mine_pose, theirs_pose.to_dict())
    truth = accuracy.analyse(run.time, run.true_position, run.true_quaternion, run.target_time,
                             run.target_position, run.target_quaternion, SETTINGS.settle,
                             end_times=run.end_time)
    assert len(analysis.replay.truth_visits) == len(truth.visits) == 30
    for mine_truth, theirs_truth in zip(analysis.replay.truth_visits, truth.visits,
                                        strict=True):
        _same_visit(mine_truth.visit, theirs_truth)
    expected_tracker = accuracy.tracker_errors(run.time, run.position, run.quaternion, run.time,
                                               run.true_position, run.true_quaternion,
                                               SETTINGS.tracker_error.max_stamp_difference)
    assert analysis.tracker is not None and expected_tracker is not None
    _same_figures(analysis.tracker.to_dict(), expected_tracker.to_dict())
    # the modes differ as the synthetic biases say: none far off, measured best
    worst = {m.mode: m.extremes.position_error_rms for m in analysis.modes}
    assert worst['none'] > 300e-6
    assert 40e-6 > worst['model'] > worst['measured']
    assert analysis.problems == () and analysis.ignored == ()


def test_analyze_writes_report_summary_and_plots(bag: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'out'
    assert main([str(bag), '--out', str(out)]) == Exit.OK
    printed = capsys.readouterr().out
    assert 'worst AP_p µm' in printed and 'measured' in printed and str(out) in printed
    text = (out / 'report.md').read_text()
    for words in ('## Comparison of compensation modes', '## Per commanded pose',
                  '## Simulation truth', 'ISO 9283', '| none |', '| measured | P5 |'):
        assert words in text
    summary = json.loads((out / 'summary.json').read_text())
    assert [m['mode'] for m in summary['modes']] == ['none', 'model', 'measured']
    assert summary['modes'][0]['poses'][1]['iso9283']['n'] == 2
    # AP_p and RP_l with their U from the tracker's stated covariances (issue 25)
    stated = summary['modes'][0]['poses'][1]['iso9283_u']
    assert 0.0 < stated['ap_p'] < 1e-4 and 0.0 < stated['rp_l'] < 1e-4, stated
    assert all(0.0 < stated[k] < 1e-3 for k in ('ap_a', 'ap_b', 'ap_c', 'rp_a', 'rp_b',
                                                 'rp_c')), stated
    assert 'AP_p ± U µm' in text and f'{stated["rp_l"] * 1e6:.1f} |' in text
    # ISO 9283 §7.3 between P2 and P4, one pair a cycle, with U
    distance = summary['modes'][0]['distance']
    assert distance['poses'] == ['P2', 'P4'] and distance['iso9283']['n'] == 2
    assert 0.0 < distance['iso9283_u']['ad_p'] < 1e-4, distance
    assert '## Distance accuracy and repeatability' in text and '| none | P2 - P4 | 2 |' in text
    assert {v['program_cycle'] for v in summary['visits'] if v['mode'] == 'none'} == {1, 2}
    # ISO 9283 §7.4, §7.5 per visit and per pose, from the same readings as the live monitor
    stabilised = summary['modes'][0]['poses'][1]['stabilisation']
    assert stabilised['cycles'] == 2 and stabilised['time_mean'] >= 0.0, stabilised
    assert all(v['stabilisation']['readings'] > 0 for v in summary['visits'])
    assert '## Pose stabilisation time and overshoot' in text and '| none | P2 | 2 |' in text
    assert summary['settings']['stabilisation_band'] == SETTINGS.stabilisation.band
    assert summary['tracker']['samples'] > 0
    pngs = {'error_over_time.png', 'axis_errors.png', 'clusters.png', 'error_distribution.png'}
    assert set(summary['plots']) == pngs
    for name in pngs:
        assert (out / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
        assert (out / name).stat().st_size > 10_000
        assert f'({name})' in text


def test_without_program_topic_the_modes_come_from_the_positioner_diagnostics(
        run: SyntheticRun, tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    write_run_bag(path, run, program=False, truth=False)
    analysis = analyse_bag(path, SETTINGS)
    assert [m.mode for m in analysis.modes] == ['none', 'model', 'measured']
    assert [p.pose for p in analysis.modes[0].poses] == ['P1', 'P2', 'P3', 'P4', 'P5']
    assert analysis.truth_modes == () and analysis.tracker is None
    assert set(analysis.missing_optional) == {'/sim/platform/true_pose', '/cell/program',
                                              '/metrology/registration'}


def test_the_replay_takes_the_recorded_registration_as_the_readings_common_part(
        run: SyntheticRun, tmp_path: Path) -> None:
    """A bag with the tracker's registration (/metrology/registration): each visit's
    covariance is the closed loop's mean with the registration's covariance at the window's
    mean position as the part every reading shares (common + (C̄ − common)/k), as the live
    monitor takes it; the same bag without it splits the readings by their scatter."""
    origin = np.array([2.0, 0.3, 0.5])
    located = np.diag([(2e-6) ** 2] * 3 + [(1e-6) ** 2] * 3)
    with_it, without = tmp_path / 'with', tmp_path / 'without'
    write_run_bag(with_it, run, tracker_registration=(origin, located))
    write_run_bag(without, run)
    a, b = analyse_bag(with_it, SETTINGS), analyse_bag(without, SETTINGS)
    assert '/metrology/registration' not in a.missing_optional
    assert len(a.replay.visits) == len(b.replay.visits) > 10
    stated = np.asarray(run.covariance)
    registration = Registration(origin, located)
    for va, vb in zip(a.replay.visits, b.replay.visits, strict=True):
        window = (run.time >= va.visit.window_start) & (run.time <= va.visit.settle_time)
        assert window.sum() == va.visit.samples
        common = registration.covariance_at(run.position[window].mean(axis=0))[0]
        np.testing.assert_allclose(va.covariance, averaged_covariance(
            stated, common, int(window.sum())), rtol=1e-9)
        q = run.quaternion[window]
        np.testing.assert_allclose(vb.covariance, mean_reading(
            run.position[window], q, np.broadcast_to(stated, (q.shape[0], 6, 6)))[2],
            rtol=1e-9)


def test_a_truncated_bag_is_analysed_as_far_as_it_is_readable(
        run: SyntheticRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / 'cut'
    write_run_bag(path, run, joint_state_rate=400.0, truncate_to=0.5)
    original = sorted(p.name for p in path.iterdir())
    out = tmp_path / 'out'
    assert main([str(path), '--out', str(out)]) == Exit.NOT_ACHIEVED
    err = capsys.readouterr().err
    assert 'not complete' in err and 'truncated' in err
    assert sorted(p.name for p in path.iterdir()) == original  # the bag is left as it was
    summary = json.loads((out / 'summary.json').read_text())
    assert any('truncated' in p for p in summary['problems'])
    assert 'truncated' in (out / 'report.md').read_text()
    n = summary['samples']['measured']
    assert 0 < n < run.time.size
    visits = summary['visits']
    assert 5 <= len(visits) < 30
    batch = _batch(run, n)  # the same figures as the readable prefix of the samples gives
    for mine, theirs in zip(visits, batch.visits, strict=False):
        _same_visit(accuracy.Visit(**{k: (tuple(v) if isinstance(v, list) else v)
                                      for k, v in mine.items()
                                      if k in accuracy.Visit.__dataclass_fields__}), theirs)


def test_no_settle_time_exceeds_the_bag_after_an_old_latched_target(
        run: SyntheticRun, bag: Path, tmp_path: Path) -> None:
    """A recorder started after a move receives that move's latched /positioner/target first,
    with its old stamp (here 140 s before the bag): the settle time of its visit counts from
    the bag's first sample, so no settle time exceeds the bag (it was 140.2 s in a 75 s bag);
    every other figure is that of the same run without the old target."""
    path = tmp_path / 'latched'
    write_run_bag(path, run, joint_state_rate=50.0, latched_target_age=140.0)
    analysis = analyse_bag(path, SETTINGS)
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    duration = info['duration']['nanoseconds'] * 1e-9
    visits = (*analysis.replay.visits, *analysis.replay.truth_visits)
    assert len(analysis.replay.visits) == len(analysis.replay.truth_visits) == 30
    assert all(0.0 <= v.settle_duration <= duration for v in visits)
    extremes = [m.extremes for m in (*analysis.modes, *analysis.truth_modes)]
    extremes += [p.extremes for m in (*analysis.modes, *analysis.truth_modes) for p in m.poses]
    assert all(e.settle_time_max <= duration and e.settle_time_mean <= duration
               for e in extremes)
    first = analysis.replay.visits[0]
    assert first.visit.target_time == pytest.approx(run.time[0] - 140.0)  # as the monitor has it
    # Already there; judged on the first window after the move's end.
    assert first.start == run.time[0] and first.visit.window_start >= run.end_time[0]
    assert first.settle_duration < run.end_time[0] - run.time[0] + 1.0
    summary = analysis.to_dict()
    assert max(v['settle_duration'] for v in summary['visits']) <= duration
    # the other visits are those of the bag without the old target
    plain = analyse_bag(bag, SETTINGS)
    for mine, theirs in zip(analysis.replay.visits[1:], plain.replay.visits[1:], strict=True):
        _same_visit(mine.visit, theirs.visit)
        assert mine.settle_duration == theirs.settle_duration == (
            theirs.visit.settle_time - theirs.visit.target_time)
        assert (mine.mode, mine.pose) == (theirs.mode, theirs.pose)


def test_a_move_before_the_first_program_step_is_left_out_of_the_mode_figures(
        run: SyntheticRun, bag: Path, tmp_path: Path) -> None:
    """run_cell homes before the program: that visit has no program step. It stays in the
    monitor's figures, is labelled 'outside program', and the mode summaries are those of the
    program's visits alone."""
    path = tmp_path / 'homed_first'
    write_run_bag(path, dataclasses.replace(run, steps=run.steps[1:]), diagnostics=False)
    analysis = analyse_bag(path, SETTINGS)
    plain = analyse_bag(bag, SETTINGS)
    first, *rest = analysis.replay.visits
    assert first.mode == OUTSIDE_PROGRAM
    assert [(v.mode, v.pose) for v in rest] == [(v.mode, v.pose) for v in plain.replay.visits[1:]]
    assert [m.mode for m in analysis.modes] == [m.mode for m in plain.modes]
    assert sum(m.extremes.n for m in analysis.modes) == len(rest)
    assert analysis.modes[0].extremes.n == plain.modes[0].extremes.n - 1
    assert len(analysis.monitor['verdicts']) == len(plain.monitor['verdicts'])
    assert '1 visit(s) outside the program (homing, calibration)' in markdown(analysis)


def test_a_move_after_a_programs_end_is_outside_every_program(
        run: SyntheticRun, bag: Path, tmp_path: Path) -> None:
    """Between two programs (a homing or calibration move after the first one's end marker,
    before the second one's first step) a visit is labelled 'outside program'; a bag without
    the end marker (recorded before it existed) gives it the first program's last step."""
    j = len(run.steps) // 2  # the visit between the two "programs"
    ended = dataclasses.replace(run, steps=(*run.steps[:j], ProgramStep.ended(run.steps[j].stamp),
                                            *run.steps[j + 1:]))
    without = dataclasses.replace(run, steps=run.steps[:j] + run.steps[j + 1:])
    labels = {}
    for name, variant in (('ended', ended), ('without', without)):
        write_run_bag(tmp_path / name, variant, diagnostics=False)
        labels[name] = [(v.mode, v.pose) for v in
                        analyse_bag(tmp_path / name, SETTINGS).replay.visits]
    plain = [(v.mode, v.pose) for v in analyse_bag(bag, SETTINGS).replay.visits]
    assert labels['ended'][j] == (OUTSIDE_PROGRAM, plain[j][1])
    assert labels['without'][j] == plain[j - 1]
    for got in labels.values():
        assert got[:j] == plain[:j] and got[j + 1:] == plain[j + 1:]


def test_not_a_bag_and_missing_topics_fail_with_a_clear_message(
        run: SyntheticRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = tmp_path / 'notes.txt'
    text.write_text('not a bag\n')
    fake = tmp_path / 'fake.mcap'
    fake.write_bytes(b'PK\x03\x04 zip, not mcap' * 10)
    empty = tmp_path / 'empty'
    empty.mkdir()
    for path in (text, fake, empty, tmp_path / 'missing'):
        assert main([str(path), '--out', str(tmp_path / 'o')]) == Exit.USAGE
        err = capsys.readouterr().err
        assert err.startswith('analyze_bag: error: ') and str(path) in err
    assert not (tmp_path / 'o').exists()
    # a bag with the targets but no measurements
    only = synthetic_run(POSITIONS[:2], QUATERNIONS[:2], modes=('none',), cycles=1)
    lean = tmp_path / 'lean'
    write_run_bag(lean, SyntheticRun(only.target_time, only.target_position,
                                     only.target_quaternion, only.steps, only.time[:0],
                                     only.position[:0], only.quaternion[:0],
                                     only.true_position[:0], only.true_quaternion[:0],
                                     only.end_time),
                  truth=False)
    assert main([str(lean)]) == Exit.USAGE
    err = capsys.readouterr().err
    assert 'lacks /metrology/pose' in err and '/positioner/target' in err


def test_the_monitor_ignores_what_it_cannot_take() -> None:
    monitor = Monitor(SETTINGS)
    wrong_frame = monitor.target(1.0, 'tracker', [0, 0, 0.2], [0, 0, 0, 1])
    assert isinstance(wrong_frame, Ignored) and monitor.measured.target is None
    assert monitor.target(1.0, 'base', [0, 0, 0.2], [0, 0, 0, 1]) is None
    assert isinstance(monitor.measurement(1.1, 'base', [0, 0, 0.2], [0, 0, 0, 2.0]), Ignored)
    taken = monitor.measurement(1.2, 'base', [0, 0, 0.2001], [0, 0, 0, 1])
    assert not isinstance(taken, Ignored) and taken.update.position_error is not None
    assert taken.update.position_error[2] == pytest.approx(1e-4) and taken.verdict is None
    older = monitor.measurement(1.15, 'base', [0, 0, 0.2], [0, 0, 0, 1])
    assert isinstance(older, Ignored) and 'earlier than the previous sample' in older.reason
    assert [i.topic for i in monitor.ignored] == ['/positioner/target', '/metrology/pose',
                                                  '/metrology/pose']
    assert "frame_id 'tracker'" in monitor.ignored[0].reason
    report = monitor.report()
    assert report['verdicts'] == {'ok': 0, 'error': 0} and report['truth'] is None


def test_monitor_settings_come_from_the_config(tmp_path: Path) -> None:
    cell = yaml.safe_load(config_path('cell.yaml').read_text())
    section = cell['accuracy_monitor']['ros__parameters']
    assert SETTINGS.settle.window == section['settle']['window']
    assert SETTINGS.settle.min_samples == section['settle']['min_samples']
    assert SETTINGS.tolerance.position == section['tolerance']['position']
    assert (SETTINGS.tracker_error.max_stamp_difference
            == section['tracker_error']['max_stamp_difference'])
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump({'accuracy_monitor': {'ros__parameters': {
        'settle': {'windw': 1.0}}}}))
    with pytest.raises(ConfigError, match='windw'):
        MonitorSettings.from_file(bad)
    assert analyze  # the work function the command line uses


def test_the_shipped_program_is_an_iso_cube_inside_the_workspace(tmp_path: Path) -> None:
    mech = Mechanism.default()
    program = load_program(config_path('program.yaml'), mech)
    assert program.names == ('P1', 'P2', 'P3', 'P4', 'P5')
    assert program.modes == ('none', 'model', 'measured') and program.cycles >= 2
    corners = program.position[1:] - program.position[0]
    np.testing.assert_allclose(np.abs(corners), 0.004, atol=1e-12)  # 0.8 x the half edge
    assert np.allclose(program.position[1:].mean(axis=0), program.position[0])
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump({'program': {'cycles': 1, 'poses': {
        'P1': {'position': [0.0, 0.0, 0.196]}, 'far': {'position': [0.0, 0.0, 0.30]}}}}))
    with pytest.raises(ConfigError, match='far is outside the workspace'):
        load_program(bad, mech)


def test_the_acceptance_program_approaches_p1_from_three_directions(tmp_path: Path) -> None:
    """config/acceptance.yaml: P1 reached three times a cycle, along −x, −y and −z (ISO 9283
    §7.2.3), P2..P5 once; a sequence naming an unknown pose is refused."""
    mech = Mechanism.default()
    program = load_program(config_path('acceptance.yaml'), mech)
    order = [program.names[k] for k in program.order]
    assert order == ['P2', 'P3', 'P4', 'P5', 'AX', 'P1', 'AY', 'P1', 'AZ', 'P1']
    assert program.moves == len(program.modes) * program.cycles * 10
    steps = [k for _, _, k in program.steps()]
    p1 = program.names.index('P1')
    approaches = {tuple(np.sign(program.position[k] - program.position[before]))
                  for before, k in itertools.pairwise(steps) if k == p1}
    assert approaches == {(-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)}
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump({'program': {'sequence': ['P1', 'P9'], 'poses': {
        'P1': {'position': [0.0, 0.0, 0.196]}}}}))
    with pytest.raises(ConfigError, match='sequence names P9, not in program'):
        load_program(bad, mech)


# -- the make run bag: the same figures as before the streaming analysis ---------------------
MAKE_RUN = Path(__file__).resolve().parent / 'data' / 'makerun'


def test_a_make_run_bag_gives_the_figures_it_gave_before() -> None:
    """test/data/makerun/bag is a `make run` recording (the calibration run, the three modes;
    the analysed topics, every tenth joint state, zstd chunks) and
    summary_before_issue15.json.gz what analyze_bag wrote for it when it still read every
    message through rosbags and replayed them one by one, and judged each visit on its first
    stable window. Reading through the index and replaying arrays gives every count, label
    and figure the judging rule does not decide again; the visits are the same ones (segment,
    mode, pose, cycle), now judged on their final settled window (after the positioner
    reported the move's end): the truth of the ``model`` and ``measured`` visits is no longer
    that of a pause before the platform had come to rest (µm before, below one µm now), and
    mode ``none`` (open loop, no correction) keeps its figures within the noise. And the
    messages go to the monitor in stamp order (:mod:`positioning_cell.accuracy.stamp_order`):
    the recorder got the tracker's readings up to 0.68 s after their stamps and the targets
    within 0.04 s, so in recorded order a reading taken before a target could fall after it.
    One visit more (pose key 31, outside the program) now closes on its last stable window,
    ending at the reading stamped 0.024 s before the next target and recorded 0.036 s after
    it; before, that reading went to the next segment and the window before it was not
    stable."""
    with gzip.open(MAKE_RUN / 'summary_before_issue15.json.gz', 'rt') as f:
        before = json.load(f)
    analysis = analyse_bag(MAKE_RUN / 'bag', SETTINGS)
    now = json.loads(json.dumps(analysis.to_dict()))
    assert not analysis.problems and len(analysis.replay.visits) == 66
    assert now['description'] == {'records': [], 'attachments': []}  # recorded before it
    for key in ('bag', 'plots', 'context', 'axis_tests', 'error_budget', 'compliance',
                'description'):  # new
        before.pop(key, None)
        now.pop(key, None)
    assert now['settings']['tolerances'].pop('decision_rule') == 'iso_14253_1'  # issue 25
    assert now['settings'].pop('stabilisation_band') == 50e-6  # ISO 9283 §7.4, §7.5
    # the bag was cut to the topics analysed then, without the tracker's registration (whose
    # covariance the visits' U has used since)
    assert now.pop('missing_optional_topics') == [
        *before.pop('missing_optional_topics'), '/metrology/registration']
    judged = ('modes', 'truth_modes', 'visits', 'monitor')
    assert differences({k: v for k, v in before.items() if k not in judged},
                       {k: v for k, v in now.items() if k not in judged}) == []
    fields = ('mode', 'pose', 'key', 'cycle', 'target_time', 'commanded_position')
    (extra,) = [i for i, v in enumerate(now['visits']) if v['key'] == 31]
    after = now['visits'][extra + 1]['target_time']
    assert 31 not in [v['key'] for v in before['visits']]
    assert 0.0 < after - now['visits'].pop(extra)['settle_time'] < 0.03
    for v in before['visits']:  # the label's name since programs mark their end
        v['mode'] = OUTSIDE_PROGRAM if v['mode'] == 'before program' else v['mode']
    assert ([[v[f] for f in fields] for v in before['visits']]
            == [[v[f] for f in fields] for v in now['visits']])
    assert all(a['window_start'] <= b['window_start']
               for a, b in zip(before['visits'], now['visits'], strict=True))
    truth_before = {m['mode']: m for m in before['truth_modes']}
    truth_now = {m['mode']: m for m in now['truth_modes']}
    for mode in ('model', 'measured'):
        assert truth_now[mode]['n'] == truth_before[mode]['n']
        assert truth_before[mode]["position_error_rms"] > 2e-6 > 2 * (
            truth_now[mode]['position_error_rms'])
    np.testing.assert_allclose(truth_now['none']['position_error_rms'],
                               truth_before['none']['position_error_rms'], rtol=0.01)
    # what only the new analysis gives: the context for the trends
    context = analysis.context
    assert [c.file is None for c in context.calibrations] == [True, False]
    assert [r.poses for r in context.calibration_runs] == [36]
    assert len(context.registrations) == 1 and context.registrations[0].residual_rms_um > 0


def test_rosbags_decoding_gives_the_same_replay_as_the_indexed_read() -> None:
    """The same bag decoded message by message by rosbags (an independent decoder) and
    batched gives the same monitor report as the indexed read with vectorised decoding."""
    with BagReader(MAKE_RUN / 'bag') as reader:
        topics = [t for t in ANALYSED_TOPICS if t in reader.topics]
        slow = replay(message_batches(reader.messages(topics), size=997), SETTINGS)
    fast = analyse_bag(MAKE_RUN / 'bag', SETTINGS).replay
    a, b = slow.monitor.report(), fast.monitor.report()
    tracker_a, tracker_b = a.pop('tracker'), b.pop('tracker')
    assert a == b and tracker_a['samples'] == tracker_b['samples']
    assert slow.segments == fast.segments and slow.program == fast.program
    assert slow.measured.count == fast.measured.count == 3030


def test_the_error_trace_keeps_a_bounded_envelope() -> None:
    """However long the run, at most `capacity` bins; per bin the min and max of the errors
    that fell in it, as a direct computation with the final bin width gives."""
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.exponential(0.05, 20_000))
    dp = rng.normal(0, 1e-5, (t.size, 3))
    rv = rng.normal(0, 1e-5, (t.size, 3))
    trace = ErrorTrace(capacity=256)
    for part in np.array_split(np.arange(t.size), 37):
        trace.add(t[part], dp[part], rv[part])
    env = trace.envelope()
    assert env.time.size <= 256 and env.count.sum() == t.size == trace.samples
    index = np.floor((t - t[0]) / trace.width).astype(int)
    d = np.linalg.norm(dp, axis=1)
    for k, (lo, hi) in enumerate(zip(env.position_min, env.position_max, strict=True)):
        mine = d[index == np.unique(index)[k]]
        assert (lo, hi) == (mine.min(), mine.max())
    short = ErrorTrace()  # a short run at the tracker's 20 Hz: every sample apart
    t20 = 1.7e9 + np.arange(50) / 20.0
    short.add(t20, dp[:50], rv[:50])
    np.testing.assert_array_equal(short.envelope().time, t20)
    np.testing.assert_array_equal(short.envelope().position_max, d[:50])


def test_an_axis_test_in_the_bag_gets_its_iso230_2_tables(tmp_path: Path) -> None:
    """The /cell/axis_test markers of a recorded axis test become the report's ISO 230-2
    tables: the figures of iso230_2 on the markers' deviations, from the tracker and, when the
    markers carry it, from the truth."""
    from rosbags.typesys import Stores, get_typestore

    from positioning_cell.accuracy import iso230_2
    from positioning_cell.analysis.axis_test import UP, AxisTestMarker
    from positioning_cell.bag import BagWriter
    from positioning_cell.names import AXIS_TEST

    rng = np.random.default_rng(11)
    targets = np.array([-0.001, -0.0003, 0.0004, 0.001])
    x = {d: rng.normal(30e-6 if d == UP else 26e-6, 2e-6, (3, 4)) for d in ('up', 'down')}
    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    stamped = 'geometry_msgs/msg/PoseStamped'
    path = tmp_path / 'axis'
    t0 = 1.7e9
    with BagWriter(path) as bag:
        for topic, msgtype in ((TARGET, stamped), (MEASURED_POSE, stamped),
                               (AXIS_TEST, 'std_msgs/msg/String')):
            bag.add_topic(topic, msgtype)
        pose = T['geometry_msgs/msg/Pose'](T['geometry_msgs/msg/Point'](0.0, 0.0, 0.196),
                                           T['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0,
                                                                              1.0))
        for k, topic in enumerate((TARGET, MEASURED_POSE)):
            t = t0 + k
            header = T['std_msgs/msg/Header'](T['builtin_interfaces/msg/Time'](int(t), 0),
                                              'base')
            bag.write(topic, stamped, bytes(store.serialize_cdr(T[stamped](header, pose),
                                                                stamped)), int(t * 1e9))
        log = t0 + 2
        for c in range(3):
            for direction in ('up', 'down'):
                for i in (range(4) if direction == 'up' else reversed(range(4))):
                    marker = AxisTestMarker('run1', 'leg2_length', i, float(targets[i]),
                                            direction, c + 1, 0.2 + targets[i],
                                            0.2 + targets[i],
                                            0.2 + targets[i] + x[direction][c, i], None, log,
                                            log + 0.2, 5)
                    text = T['std_msgs/msg/String'](marker.to_json())
                    bag.write(AXIS_TEST, 'std_msgs/msg/String',
                              bytes(store.serialize_cdr(text, 'std_msgs/msg/String')),
                              int(log * 1e9))
                    log += 1.0
    analysis = analyse_bag(path, SETTINGS)
    (test,) = analysis.axis_tests
    (result,) = test.results  # the tracker's (no truth in these markers)
    expected = iso230_2(targets, targets + x['up'], targets + x['down'])
    assert (result.axis, result.source) == ('leg2_length', 'tracker')
    for name in ('A', 'R', 'B', 'B_mean', 'E', 'E_up', 'E_down', 'M'):
        assert getattr(result.figures, name) == pytest.approx(getattr(expected, name),
                                                              rel=1e-9, abs=1e-15)
    text = markdown(analysis)
    assert '## Axis test (ISO 230-2), run run1' in text and 'leg2_length' in text
    assert analysis.to_dict()['axis_tests'][0]['results'][0]['axis'] == 'leg2_length'


def test_a_pose_approached_from_three_directions_gets_its_vap(tmp_path: Path) -> None:
    """ISO 9283 §7.2.3 from a recorded run: P1 is commanded between excursions 4 mm along +x,
    +y and +z, so after the first cycle's first visit it is approached from −x, −y and −z;
    vAP is that of its attained poses grouped so (the library's function on the replayed
    visits), and the report has its table."""
    centre = POSITIONS[0]
    positions = np.array([centre, centre + [0.004, 0, 0], centre, centre + [0, 0.004, 0],
                          centre, centre + [0, 0, 0.004]])
    run = synthetic_run(positions, np.tile([0.0, 0.0, 0.0, 1.0], (6, 1)), modes=('none',),
                        cycles=2, dwell_time=1.5, seed=3)
    names = ('P1', 'X', 'P1', 'Y', 'P1', 'Z')
    run = dataclasses.replace(run, steps=tuple(
        dataclasses.replace(s, pose=names[k % 6]) for k, s in enumerate(run.steps)))
    write_run_bag(tmp_path / 'run', run, joint_state_rate=50.0)
    analysis = analyse_bag(tmp_path / 'run')
    p1 = next(p for p in analysis.modes[0].poses if p.pose == 'P1')
    v = p1.multidirectional
    assert v is not None and v.directions == 3 and v.n == 5  # the first visit: no approach
    visits = [lv.visit for lv in analysis.replay.visits if lv.pose == 'P1'][1:]
    approach = [(-1, 0, 0), (0, -1, 0), (0, 0, -1)] * 2
    expected = accuracy.multidirectional_figures(
        [0, 0, 0, 1], [x.position for x in visits], [x.quaternion for x in visits],
        approach[:len(visits)])
    assert expected is not None
    assert v.vap_p == pytest.approx(expected.vap_p, rel=1e-9) and 0.0 < v.vap_p < 50e-6
    assert sorted(v.approaches) == sorted([(-1.0, 0.0, 0.0), (0.0, -1.0, 0.0),
                                           (0.0, 0.0, -1.0)])
    text = markdown(analysis)
    assert '## Multi-directional pose accuracy variation' in text
    assert f'| none | P1 | 3 | 5 | {v.vap_p * 1e6:.1f} ± ' in text
    assert 0.0 < p1.multidirectional_u < 50e-6  # from the readings' stated covariances
    assert all(0.0 < u < 1e-3 for u in p1.multidirectional_angles_u)  # rad, and stated
    assert 'vAP_a ± U °' in text


def test_distance_pairs_are_one_cycle_each_even_when_a_cycle_missed_a_pose() -> None:
    """ISO 9283 §7.3 pairs the two poses of one cycle: P4 missed in cycle 2 leaves cycles 1
    and 3, not (1, 1), (2, 3); a retried pose's last visit counts; without program cycles the
    visits pair in order."""
    from positioning_cell.analysis.replay import LabelledVisit
    from positioning_cell.analysis.summary import cycle_pairs

    def visits(pose: str, cycles: list[int | None]) -> list[LabelledVisit]:
        return [LabelledVisit(object(), 'model', pose, object(), 0.0, cycle=c)  # type: ignore[arg-type]
                for c in cycles]

    p2 = visits('P2', [1, 2, 3, 3])
    first, second = cycle_pairs(p2, visits('P4', [1, 3]))
    assert [v.cycle for v in first] == [1, 3] == [v.cycle for v in second]
    assert first[1] is p2[3]  # the retry's
    first, second = cycle_pairs(visits('P2', [None, None, None]), visits('P4', [None, None]))
    assert len(first) == len(second) == 2


def test_the_command_runs_its_analysis_on_one_blas_thread(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """analyze_bag sets its process's environment (ANALYSIS_ENVIRONMENT: one OpenBLAS thread,
    so that the plot workers keep the other core) before numpy would load, keeping a value the
    user gave; in a fresh process numpy is not loaded by the command's module."""
    from positioning_cell.tools.analyze_bag import ANALYSIS_ENVIRONMENT
    monkeypatch.delenv('OPENBLAS_NUM_THREADS', raising=False)
    assert main([str(tmp_path / 'missing')]) == Exit.USAGE
    assert ANALYSIS_ENVIRONMENT == {'OPENBLAS_NUM_THREADS': '1'}
    assert os.environ['OPENBLAS_NUM_THREADS'] == '1'
    monkeypatch.setenv('OPENBLAS_NUM_THREADS', '2')
    main([str(tmp_path / 'missing')])
    assert os.environ['OPENBLAS_NUM_THREADS'] == '2'
    loaded = subprocess.run(
        [sys.executable, '-c', 'import sys, positioning_cell.tools.analyze_bag; '
         'print("numpy" in sys.modules)'], capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == 'False'
