"""Fleet trends (positioning_cell.analysis.fleet, fleet_report, tools/analyze_bags): the trends
and the drift since calibration against hand-computed values on synthetic digests, finding bags
in a folder tree, and the command line on small synthetic bags on a Dask LocalCluster of two
workers (the figures equal those of each bag analysed alone; a bag that fails is reported while
the others are analysed)."""

from __future__ import annotations

import json
import math
import os
import pickle
import random
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from positioning_cell.accuracy import PoseFigures
from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.context import CalibrationInForce, CalibrationRun, Registration
from positioning_cell.analysis.fleet import (
    BagFailure,
    PoseDigest,
    RunDigest,
    digest_bag,
    find_bags,
    identify_poses,
    trends,
)
from positioning_cell.analysis.fleet_report import markdown, write_report
from positioning_cell.errors import InputError
from positioning_cell.testing.nested import assert_nested_close
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag
from positioning_cell.tools import analyze_bags
from positioning_cell.tools.exits import Exit

UM = 1e-6
P1, P2, P3 = (0.0, 0.0, 0.196), (0.004, 0.004, 0.2), (-0.004, -0.004, 0.2)
P2_MOVED = (0.008, 0.0, 0.2)  # named P2 by a later program: another pose


def figures(commanded: Sequence[float], offset_um: Sequence[float],
            angles_urad: Sequence[float] = (0.0, 0.0, 0.0), n: int = 3) -> PoseFigures:
    """ISO 9283 figures of a pose whose barycentre is ``offset_um`` from ``commanded`` (m) and
    mean angles ``angles_urad`` from the commanded (identity) orientation; RP_l 2 µm and RP_abc
    3 µrad with two visits or more."""
    c = np.asarray(commanded, dtype=float)
    d = np.asarray(offset_um, dtype=float) * UM
    a = np.asarray(angles_urad, dtype=float) * UM
    rp = n >= 2
    return PoseFigures(
        key=0, n=n, commanded_position=(float(c[0]), float(c[1]), float(c[2])),
        commanded_quaternion=(0.0, 0.0, 0.0, 1.0), commanded_angles=(0.0, 0.0, 0.0),
        barycentre=(float(c[0] + d[0]), float(c[1] + d[1]), float(c[2] + d[2])),
        ap_x=float(d[0]), ap_y=float(d[1]), ap_z=float(d[2]),
        ap_p=float(np.linalg.norm(d)), ap_a=float(a[0]), ap_b=float(a[1]), ap_c=float(a[2]),
        l_mean=1e-6, s_l=1e-6 / 3 if rp else None, rp_l=2e-6 if rp else None,
        s_a=1e-6 if rp else None, s_b=1e-6 if rp else None, s_c=1e-6 if rp else None,
        rp_a=3e-6 if rp else None, rp_b=3e-6 if rp else None, rp_c=3e-6 if rp else None)


def pose(mode: str, name: str, time: float, commanded: Sequence[float],
         offset_um: Sequence[float], **kw: Any) -> PoseDigest:
    return PoseDigest(mode, name, time, figures(commanded, offset_um, **kw))


def registration(time: float, residuals: Sequence[float], vf: float) -> Registration:
    r = np.asarray(residuals)
    return Registration(time, 1, float(np.sqrt((r * r).mean())), float(r.max()),
                        tuple(residuals), vf, (1.0, 1.0, 1.0), (2.0, 2.0, 2.0))


def fleet() -> list[RunDigest]:
    """Five runs: r1, r2 on cal_A (r2 without the model mode and pose P3); a calibration run
    at 2950 and cal_B loaded at 2990 during r3; r4 on cal_B (P1 commanded 3 µm off: the same
    pose; P3 again; a new pose named P2); r5: a calibration run that rewrote cal_B."""
    a, b = 'cal_A.yaml', 'cal_B.yaml'
    reg1 = registration(1001.0, (2.0, 5.0, 8.0), 1.1)
    return [
        RunDigest('/runs/r1/bag', 1000.0, 1500.0, 100, (
            pose('none', 'P1', 1100.0, P1, (100, 0, 0)),
            pose('none', 'P2', 1110.0, P2, (0, 50, 0)),
            pose('none', 'P3', 1120.0, P3, (0, 0, 30)),
            pose('model', 'P1', 1200.0, P1, (10, 0, 0)),
            pose('model', 'P2', 1210.0, P2, (0, 5, 0))), a,
            (CalibrationInForce(1000.0, a),), (), (reg1,)),
        RunDigest('/runs/r2/bag', 2000.0, 2500.0, 100, (
            pose('none', 'P1', 2100.0, P1, (103, 4, 0), angles_urad=(20, 0, -10)),
            pose('none', 'P2', 2110.0, P2, (0, 50, 12))), a,
            (CalibrationInForce(2000.0, a),), (), (registration(2001.0, (2.0, 5.0, 8.0), 1.1),)),
        RunDigest('/runs/r3/bag', 2900.0, 3500.0, 100, (
            pose('none', 'P1', 3100.0, P1, (20, 0, 0)),
            pose('none', 'P2', 3110.0, P2, (0, 10, 0)),
            pose('model', 'P1', 3200.0, P1, (2, 0, 0)),
            pose('model', 'P2', 3210.0, P2, (0, 1, 0))), b,
            (CalibrationInForce(2900.0, a), CalibrationInForce(2990.0, b)),
            (CalibrationRun('c1', 2950.0, 30),), (registration(2901.0, (3.0, 4.0, 2.0), 0.9),)),
        RunDigest('/runs/r4/bag', 4000.0, 4500.0, 100, (
            pose('none', 'P1', 4100.0, (3e-6, 0.0, 0.196), (22, 0, 0)),
            pose('none', 'P2', 4110.0, P2_MOVED, (0, 0, 7), n=1),
            pose('none', 'P3', 4120.0, P3, (0, 0, 35)),
            pose('model', 'P1', 4200.0, P1, (2, 3, 0))), b,
            (CalibrationInForce(4000.0, b),), (), (), ('the bag is damaged: 1 corrupt chunk',)),
        RunDigest('/runs/r5/bag', 5000.0, 5500.0, 100, (
            pose('none', 'P1', 5100.0, P1, (30, 0, 0)),), b,
            (CalibrationInForce(5000.0, b),), (CalibrationRun('c2', 5010.0, 30),)),
    ]


def shuffled(digests: list[RunDigest]) -> list[RunDigest]:
    out = list(digests)
    random.Random(3).shuffle(out)
    return out


def test_series_per_mode_and_pose_in_time_order() -> None:
    t = trends(shuffled(fleet()))
    assert [r.bag for r in t.runs] == [f'/runs/r{k}/bag' for k in range(1, 6)]
    assert t.modes == ('none', 'model')
    assert [p.name for p in t.poses] == ['P1', 'P2', 'P3', 'P2#2']
    assert t.poses[3].position == P2_MOVED
    assert [(s.mode, s.pose.name) for s in t.series] == [
        ('none', 'P1'), ('none', 'P2'), ('none', 'P3'), ('none', 'P2#2'), ('model', 'P1'),
        ('model', 'P2')]
    none_p1, none_p2, none_p3, moved, model_p1, model_p2 = t.series
    assert none_p1.time.tolist() == [1100.0, 2100.0, 3100.0, 4100.0, 5100.0]  # r4's P1 too
    assert none_p1.bags[3] == '/runs/r4/bag'
    np.testing.assert_allclose(none_p1.ap_p / UM, [100, math.hypot(103, 4), 20, 22, 30])
    np.testing.assert_allclose(none_p1.ap[:, :2] / UM, [[100, 0], [103, 4], [20, 0], [22, 0],
                                                         [30, 0]], atol=1e-9)
    np.testing.assert_allclose(none_p1.ap_angles[1] / UM, [20, 0, -10])
    np.testing.assert_allclose(none_p1.rp_l, 2e-6)
    assert none_p3.time.tolist() == [1120.0, 4120.0]  # missing in r2, r3
    assert model_p1.time.tolist() == [1200.0, 3200.0, 4200.0]  # model missing in r2
    assert model_p2.time.tolist() == [1210.0, 3210.0]
    assert none_p2.n.tolist() == [3, 3, 3]
    assert moved.n.tolist() == [1] and np.isnan(moved.rp_l).all()
    assert np.isnan(moved.rp_angles).all()


def test_epochs_start_at_a_calibration_file_change_or_run() -> None:
    t = trends(fleet())
    # Events: run c1 at 2950 (epoch 1: nothing observed in it), cal_B at 2990 (2), run c2
    # at 5010 (3: cal_B rewritten by a calibration, the file name unchanged).
    assert [(e.index, e.start, e.calibration) for e in t.epochs] == [
        (0, None, 'cal_A.yaml'), (2, 2990.0, 'cal_B.yaml'), (3, 5010.0, 'cal_B.yaml')]
    assert t.epochs[0].bags == ('/runs/r1/bag', '/runs/r2/bag')
    assert t.epochs[1].bags == ('/runs/r3/bag', '/runs/r4/bag')
    assert t.epochs[1].cause == 'calibration file cal_B.yaml in force'
    assert t.epochs[2].cause == 'calibration run c2' and t.epochs[2].bags == ('/runs/r5/bag',)
    assert t.series[0].epoch.tolist() == [0, 0, 2, 2, 3]


def test_drift_since_calibration_resets_at_each_epoch() -> None:
    t = trends(fleet())
    none_p1, _, none_p3, _, model_p1, _ = t.series
    # r2 against r1: (103, 4) - (100, 0) = (3, 4) µm; r3 starts epoch 2: 0; r4 against r3:
    # barycentre 3 + 22 against 20 = 5 µm (its commanded pose 3 µm off); r5 starts epoch 3.
    np.testing.assert_allclose(none_p1.drift / UM, [[0, 0, 0], [3, 4, 0], [0, 0, 0],
                                                    [5, 0, 0], [0, 0, 0]], atol=1e-6)
    np.testing.assert_allclose(none_p1.drift_distance / UM, [0, 5, 0, 5, 0], atol=1e-6)
    np.testing.assert_allclose(none_p1.drift_angles[1] / UM, [20, 0, -10], atol=1e-9)
    np.testing.assert_allclose(none_p1.drift_angles[[0, 2, 3, 4]], 0.0, atol=1e-15)
    # A pose missing from the epoch's first run: against its first run in the epoch.
    np.testing.assert_allclose(none_p3.drift, 0.0, atol=1e-15)
    # A mode missing from a run: that run is not in the series.
    np.testing.assert_allclose(model_p1.drift / UM, [[0, 0, 0], [0, 0, 0], [0, 3, 0]],
                               atol=1e-6)


def test_registrations_over_time_without_repeats() -> None:
    r = trends(shuffled(fleet())).registrations
    assert r.time.tolist() == [1001.0, 2901.0]  # r2 saw r1's registration again
    assert r.bags == ('/runs/r1/bag', '/runs/r3/bag')
    np.testing.assert_allclose(r.residual_rms / UM, [math.sqrt(93 / 3), math.sqrt(29 / 3)])
    np.testing.assert_allclose(r.residual_max / UM, [8.0, 4.0])
    assert r.variance_factor.tolist() == [1.1, 0.9]


def test_poses_identified_by_commanded_pose_within_tolerance() -> None:
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    turned = Rotation.from_rotvec([0.0, 0.0, 1e-4]).as_quat()
    p = np.array([P1, P1, np.add(P1, [5e-6, 0, 0]), np.add(P1, [2e-5, 0, 0]), P1, P1])
    q = np.array([q0, -q0, q0, q0, turned, q0])
    poses, index = identify_poses(p, q, ['A', 'B', 'C', 'D', 'E', 'F'])
    assert [c.name for c in poses] == ['A', 'D', 'E']
    assert index.tolist() == [0, 0, 0, 1, 2, 0]
    poses, index = identify_poses(p, q, ['A'] * 6, position_tolerance=1e-4,
                                  angle_tolerance=1e-3)
    assert [c.name for c in poses] == ['A'] and index.tolist() == [0] * 6


def test_digests_pickle_and_trends_are_json() -> None:
    runs = fleet()
    assert pickle.loads(pickle.dumps(runs)) == runs
    doc = json.loads(json.dumps(trends(runs).to_dict(), allow_nan=False))
    moved = next(s for s in doc['series'] if s['pose'] == 'P2#2')
    assert moved['rp_l'] == [None] and moved['ap_p'] == [pytest.approx(7e-6)]
    assert doc['epochs'][1]['calibration'] == 'cal_B.yaml'
    with pytest.raises(InputError, match='more than once'):
        trends([runs[0], runs[0]])
    empty = trends([])
    assert empty.series == () and empty.epochs == () and empty.registrations.time.size == 0


def test_report(tmp_path: Path) -> None:
    t = trends(fleet())
    plots = [tmp_path / 'trend_accuracy.png']  # the plots are drawn in the command-line test
    md, js = write_report(t, tmp_path, plots=plots)
    text = md.read_text()
    assert '1970-01-01 00:49:50' in text  # epoch 2 from 2990 s, in UTC
    assert 'P2#2' in text and 'r4/bag: the bag is damaged' in text
    assert '| 2 | none | P1 | 2 | 5.0 | 5.0 | 5.0, 0.0, 0.0 |' in text  # drift in epoch 2
    assert '| r2/bag | 1970-01-01 00:33:20 | 5.0 (e0) | 12.0 (e0) | – | – |' in text
    assert '![trend_accuracy](trend_accuracy.png)' in text
    assert json.loads(js.read_text())['plots'] == ['trend_accuracy.png']
    assert 'No bag could be analysed' in markdown(trends([]))


def test_find_bags_in_a_folder_tree(tmp_path: Path) -> None:
    def touch(rel: str) -> Path:
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b'')
        return path

    touch('plant/a/bag1/metadata.yaml')
    inner = touch('plant/a/bag1/bag1_0.mcap')
    touch('plant/a/bag1/more/x.mcap')  # inside a bag folder: part of that bag
    touch('plant/a/loose.mcap')
    touch('plant/b/c/run.mcap')
    touch('plant/b/c/notes.txt')
    (tmp_path / 'empty/sub').mkdir(parents=True)
    bags = [tmp_path / 'plant/a/bag1', tmp_path / 'plant/a/loose.mcap',
            tmp_path / 'plant/b/c/run.mcap']
    assert find_bags([tmp_path / 'plant']) == bags
    assert find_bags([tmp_path / 'plant/b', inner, tmp_path / 'plant/a/bag1']) == [
        bags[0], bags[2]]
    for bad, what in (('empty', 'no bag in this folder'), ('plant/b/c/notes.txt', 'not a bag'),
                      ('nowhere', 'no such file')):
        with pytest.raises(InputError, match=what) as err:
            find_bags([tmp_path / 'plant', tmp_path / bad])
        assert bad in str(err.value)


# -- the command line on bags, on a LocalCluster of two workers ------------------------------
POSITIONS = np.array([P1, P2])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))
DAY = 86400.0


@pytest.fixture
def scheduler() -> Iterator[str]:
    """The address of a Dask scheduler on 127.0.0.1 with one worker thread in this process
    (starts in a second; stopped at the end)."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol='tcp',
                      host='127.0.0.1', dashboard_address=None) as c:
        yield c.scheduler_address


def write_fleet(root: Path) -> list[Path]:
    """Four small runs a day apart (the third recalibrated, the second without the model
    mode, the fourth truncated: its .mcap file without metadata.yaml is the bag) and a bag
    that fails: garbage in an .mcap file. The bags as find_bags names them."""
    runs = [  # (name, modes, calibration file, calibration run, registration residuals µm)
        ('2026-03-01/bag', ('none', 'model'), 'cal_A.yaml', None, (4.0, 6.0, 5.0)),
        ('2026-03-02/bag', ('none',), 'cal_A.yaml', None, (4.5, 6.5, 5.0)),
        ('2026-03-03/bag', ('none', 'model'), 'cal_B.yaml', '2026-03-03T06:00:00Z', (3.0,)),
        ('2026-03-04/bag', ('none', 'model'), 'cal_B.yaml', None, None)]
    bags = []
    for k, (name, modes, cal, cal_run, reg) in enumerate(runs):
        run = synthetic_run(POSITIONS, QUATERNIONS, modes=modes, cycles=2, rate=10.0,
                            dwell_time=1.5, start=1.77e9 + k * DAY, seed=k,
                            visit_sigma=2e-6 * (k + 1))
        write_run_bag(root / name, run, calibration=cal, calibration_run=cal_run,
                      registration_um=reg, truncate_to=0.7 if k == 3 else None)
        bags.append(root / name if k < 3 else next((root / name).glob('*.mcap')))
    (root / 'broken').mkdir()
    (root / 'broken' / 'garbage.mcap').write_bytes(b'not an mcap file at all' * 10)
    return bags


def test_the_local_workers_run_without_dasks_trim_threshold() -> None:
    """The local cluster's workers keep Dask's environment (one BLAS thread each) but not its
    glibc trim threshold (analyze_bags.worker_environment: set, it made a bag's analysis
    in a worker 1.7 times slower); Dask's own setting is left as it was."""
    before = analyze_bags.dask_config().get(analyze_bags.PRE_SPAWN_ENVIRON)
    assert analyze_bags.TRIM_THRESHOLD in before  # what the test is about
    with analyze_bags.dask_client(workers=1) as client:
        seen = client.run(lambda: {k: os.environ.get(k) for k in (
            analyze_bags.TRIM_THRESHOLD, 'OPENBLAS_NUM_THREADS')})
    assert list(seen.values()) == [{analyze_bags.TRIM_THRESHOLD: None,
                                    'OPENBLAS_NUM_THREADS': '1'}]
    assert analyze_bags.dask_config().get(analyze_bags.PRE_SPAWN_ENVIRON) == before


def _profiling(dask_worker: Any) -> bool:
    """Whether a worker samples its task threads' stacks (Dask's statistical profiler: a
    periodic callback of the worker's event loop, set up when the worker starts)."""
    return 'profile' in dask_worker.periodic_callbacks


@pytest.mark.parametrize('profile', [False, True])
def test_the_local_workers_profile_only_when_asked(profile: bool) -> None:
    """Dask's statistical profiler is off on the local workers unless asked for
    (analyze_bags.WORKER_PROFILE: it cost a bag's analysis about 11 % of its CPU); Dask's own
    setting is left as it was."""
    before = analyze_bags.dask_config().get(analyze_bags.WORKER_PROFILE)
    with analyze_bags.dask_client(workers=2, profile=profile) as client:
        assert list(client.run(_profiling).values()) == [profile, profile]
    assert analyze_bags.dask_config().get(analyze_bags.WORKER_PROFILE) == before


def test_the_command_line_on_a_local_cluster(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The default: a LocalCluster of worker processes (two here), started and stopped by the
    command."""
    bags = write_fleet(tmp_path / 'plant')
    out = tmp_path / 'trends'
    code = analyze_bags.main([str(tmp_path / 'plant'), '--out', str(out), '--workers', '2'])
    printed = capsys.readouterr()
    assert code == Exit.NOT_ACHIEVED, printed
    assert '5 bag(s) on 2 local worker process(es)' in printed.out and '[5/5]' in printed.out
    assert 'garbage.mcap: FAILED' in printed.out
    assert 'failed: ' in printed.err and 'garbage.mcap' in printed.err
    doc = json.loads((out / 'trends.json').read_text())
    assert len(doc['failed']) == 1 and doc['failed'][0]['bag'].endswith('garbage.mcap')
    assert [Path(r['bag']) for r in doc['runs']] == bags
    # The figures are those of each bag analysed alone.
    alone = {str(b): analyse_bag(b) for b in bags}
    compared = 0
    for s in doc['series']:
        for k, bag in enumerate(s['bags']):
            mode = next(m for m in alone[bag].modes if m.mode == s['mode'])
            f = next(p.figures for p in mode.poses if p.pose == s['pose'])
            assert_allclose([s['ap_p'][k], s['rp_l'][k]], [f.ap_p, f.rp_l], rtol=1e-12,
                            atol=1e-15)
            assert_allclose(s['ap'][k], [f.ap_x, f.ap_y, f.ap_z], rtol=1e-12, atol=1e-15)
            assert_allclose(s['barycentre'][k], f.barycentre, rtol=1e-12, atol=1e-15)
            assert s['n'][k] == f.n
            # with the U of AP_p and RP_l and each visit's decision (issue 25)
            u = next(p.uncertainty for p in mode.poses if p.pose == s['pose'])
            assert s['ap_p_u'][k] == pytest.approx(u.ap_p, rel=1e-12) and u.ap_p > 0.0
            assert sum(s['decisions'][k]) == f.n
            compared += 1
    assert compared == sum(len(p.poses) for a in alone.values() for p in a.modes) >= 12
    # Epochs: cal_A, then the recalibration of the third run (its calibration run first,
    # then its new file: the drift restarts at the third run).
    epochs = doc['epochs']
    assert [e['calibration'] for e in epochs] == ['cal_A.yaml', 'cal_B.yaml']
    assert [len(e['bags']) for e in epochs] == [2, 2]
    none_p1 = next(s for s in doc['series'] if (s['mode'], s['pose']) == ('none', 'P1'))
    assert none_p1['epoch'][0] == 0 and none_p1['epoch'][2] > 0
    assert none_p1['drift_distance'][0] == none_p1['drift_distance'][2] == 0.0
    assert none_p1['drift_distance'][1] > 0.0
    model_p1 = next(s for s in doc['series'] if (s['mode'], s['pose']) == ('model', 'P1'))
    assert str(bags[0]) in model_p1['bags'] and str(bags[2]) in model_p1['bags']
    assert str(bags[1]) not in model_p1['bags']  # the second run had no model mode
    assert len(doc['registrations']['time']) == 3
    assert doc['registrations']['residual_max'] == [pytest.approx(6e-6), pytest.approx(6.5e-6),
                                                    pytest.approx(3e-6)]
    problems = doc['runs'][3]['problems']
    assert problems and 'not complete' in ' '.join(problems)
    assert {p.name for p in out.glob('*.png')} == {
        'trend_accuracy.png', 'trend_repeatability.png', 'trend_drift.png',
        'trend_registrations.png'}
    report = (out / 'trends.md').read_text()
    assert 'garbage.mcap' in report and '### none: AP_p ± U µm per run' in report
    assert '### none: visits that conform / are indeterminate / do not conform per run' in report
    # The whole report's figures are those of the serial loop in this process.
    results = [digest_bag(b) for b in find_bags([tmp_path / 'plant'])]
    serial = analyze_bags.report_fleet([r for r in results if isinstance(r, RunDigest)],
                                       [r for r in results if isinstance(r, BagFailure)],
                                       tmp_path / 'serial')
    expected = json.loads(serial.summary.read_text())
    for d in (doc, expected):
        d['failed'].sort(key=lambda f: f['bag'])
    assert_nested_close(doc, expected, rtol=1e-12, atol=1e-15)


def test_the_command_line_on_a_scheduler(tmp_path: Path, scheduler: str,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    run = synthetic_run(POSITIONS, QUATERNIONS, modes=('none',), cycles=2, rate=10.0,
                        dwell_time=1.5)
    write_run_bag(tmp_path / 'bag', run)
    out = tmp_path / 'trends'
    code = analyze_bags.main([str(tmp_path / 'bag'), '--out', str(out), '--scheduler',
                              scheduler])
    printed = capsys.readouterr().out
    assert code == Exit.OK, printed
    assert f'1 bag(s) on the scheduler at {scheduler}' in printed and '[1/1]' in printed
    ap_p = json.loads((out / 'trends.json').read_text())['series'][0]['ap_p']
    assert ap_p == [analyse_bag(tmp_path / 'bag').modes[0].poses[0].figures.ap_p]


def test_a_task_lost_outside_the_analysis_is_a_failure() -> None:
    class Lost:
        def __init__(self, status: str) -> None:
            self.status = status

        def exception(self) -> BaseException:
            return RuntimeError('worker tcp://127.0.0.1:1 died')

    lost = analyze_bags._outcome(Lost('error'), '/runs/r1/bag')
    assert isinstance(lost, BagFailure) and lost.bag == '/runs/r1/bag'
    assert 'RuntimeError: worker' in lost.reason
    assert analyze_bags._outcome(Lost('cancelled'), 'b') == BagFailure(
        'b', 'the task was cancelled')


def test_nothing_to_analyse(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                            monkeypatch: pytest.MonkeyPatch) -> None:
    assert analyze_bags.main([str(tmp_path / 'missing')]) == Exit.USAGE
    assert 'missing: no such file or folder' in capsys.readouterr().err
    (tmp_path / 'a.mcap').write_bytes(b'')
    monkeypatch.setattr(analyze_bags, 'CONNECT_TIMEOUT', 0.5)
    code = analyze_bags.main([str(tmp_path / 'a.mcap'), '--scheduler', 'tcp://127.0.0.1:9'])
    assert code == Exit.NOT_THERE
    assert 'cannot reach the Dask scheduler at tcp://127.0.0.1:9' in capsys.readouterr().err


def test_largest_bags_first(tmp_path: Path) -> None:
    """The tasks go out largest bag first (a folder bag's files summed; a path that cannot
    be read counts as empty: its task says why); equal sizes keep their order."""
    folder = tmp_path / 'folder_bag'
    folder.mkdir()
    (folder / 'metadata.yaml').write_bytes(b'x' * 100)
    (folder / 'bag_0.mcap').write_bytes(b'x' * 1000)
    small, middle, twin = (tmp_path / f'{n}.mcap' for n in ('small', 'middle', 'twin'))
    small.write_bytes(b'x' * 10)
    middle.write_bytes(b'x' * 500)
    twin.write_bytes(b'x' * 500)
    gone = tmp_path / 'gone.mcap'
    assert analyze_bags.bag_bytes(folder) == 1100 and analyze_bags.bag_bytes(gone) == 0
    assert analyze_bags.largest_first([gone, small, middle, folder, twin]) == [
        folder, middle, twin, small, gone]


def test_nested_close_finds_the_first_difference() -> None:
    """assert_nested_close passes within the tolerance (NaN equal to NaN) and names where a
    figure, a key, a length, a string or a type differs."""
    doc = {'runs': [{'bag': 'a', 'start': 1.77e9, 'n': 3, 'ap': [1e-6, math.nan, None]}]}
    near = json.loads(json.dumps(doc).replace('1e-06', '1.0000000000001e-06'))
    assert_nested_close(near, doc, rtol=1e-9)
    cases = [({'runs': [{**doc['runs'][0], 'start': 1.77e9 + 10.0}]}, "['start']"),
             ({'runs': [{**doc['runs'][0], 'ap': [2e-6, math.nan, None]}]}, "['ap'][0]"),
             ({'runs': [{**doc['runs'][0], 'bag': 'b'}]}, "['bag']"),
             ({'runs': [{**doc['runs'][0], 'n': 3.0}]}, "['n']"),
             ({'runs': []}, "['runs']"),
             ({'runs': [{'bag': 'a'}]}, "['runs'][0]"),
             ({'runs': [{**doc['runs'][0], 'ap': [1e-6, 0.0, None]}]}, "['ap'][1]")]
    for changed, where in cases:
        with pytest.raises(AssertionError, match=re.escape(where)):
            assert_nested_close(changed, doc, rtol=1e-9)


def test_an_interactive_session_is_listed_apart_not_trended(tmp_path: Path) -> None:
    """A bag without /cell/program steps (`cell up`, then moves by hand): its moves are no
    program's poses. They stay out of the ISO 9283 series (a 4 mm "AP_p" point among
    micrometres, before), and the report lists the run as interactive."""
    run = synthetic_run(POSITIONS, QUATERNIONS, modes=('none',), cycles=2, rate=10.0,
                        dwell_time=1.5, start=1.77e9, seed=9)
    write_run_bag(tmp_path / 'by_hand', run, program=False)
    digest = digest_bag(tmp_path / 'by_hand')
    assert isinstance(digest, RunDigest) and not digest.program and digest.poses
    far = RunDigest('/runs/by_hand/bag', 3000.0, 3100.0, 50, (
        pose('none', 'P1', 3050.0, P1, (4000, 0, 0)),), 'cal_A.yaml', kind='interactive')
    with_it, without = trends([*fleet(), far]), trends(fleet())
    assert [s.time.tolist() for s in with_it.series] == \
        [s.time.tolist() for s in without.series]  # 3050 in no series
    assert far in with_it.runs
    text = markdown(with_it)
    assert '| by_hand/bag | interactive |' in text and '| r1/bag | program |' in text
