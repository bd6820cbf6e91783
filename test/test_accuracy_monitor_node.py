"""The accuracy_monitor node in the test process: error topics, settled-pose verdicts on
/diagnostics, the report equal to the library's batch analysis of the same samples, reset, and
validated tolerance parameters; the recording's state from the recorder's status (failed,
silent)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from cell_harness import CELL_YAML, Client, InProcess, in_process, wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Vector3Stamped
from rcl_interfaces.srv import GetParameters
from scipy.spatial.transform import Rotation
from std_srvs.srv import Trigger

from positioning_cell import accuracy as acc
from positioning_cell import names
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.nodes.accuracy_monitor_node import AccuracyMonitorNode
from positioning_cell.recording import SILENT_AFTER_S
from positioning_cell.ros.messages import diagnostic, pose_msg, pose_stamped, status_level
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, STREAM_QOS

pytestmark = pytest.mark.nodes

HOME = np.array([0.0, 0.0, 0.19596])
RATE = 50.0  # Hz, synthetic tracker
VISIT = 1.2  # s of samples per visit: 0.3 s moving, then still
POSES = {'A': (HOME + [0.002, 0.0, 0.0], [0.0, 0.0, 0.0]),
         'B': (HOME + [0.0, -0.003, 0.002], [0.01, -0.005, 0.0])}
# Measured − commanded at rest: A within the default 50 µm (30 µm), B outside it (80 µm).
OFFSETS = {'A': np.array([18e-6, -24e-6, 0.0]), 'B': np.array([0.0, 48e-6, 64e-6])}
TRACKER_BIAS = np.array([4e-6, 0.0, -3e-6])  # measured − true, m
#: The covariance each reading states: its noise (3 µm, 10 µrad per axis), not the bias.
STATED = np.diag([(3e-6) ** 2] * 3 + [(1e-5) ** 2] * 3)


def settings() -> acc.SettleSettings:
    """The settle settings the node reads from config/cell.yaml."""
    params = node_parameters(load_parameter_file(CELL_YAML), 'accuracy_monitor')
    return acc.SettleSettings.from_params(params['settle'])


def stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class Cell:
    """The test side: publishes targets, measurements and truth and keeps what it sent."""

    def __init__(self, client: Client) -> None:
        self.client = client
        node = client.node
        self.pub_target = node.create_publisher(PoseStamped, '/positioner/target', LATCHED_QOS)
        self.pub_meas = node.create_publisher(PoseWithCovarianceStamped, '/metrology/pose',
                                              STREAM_QOS)
        self.pub_truth = node.create_publisher(PoseStamped, '/sim/platform/true_pose',
                                               STREAM_QOS)
        self.position_errors = client.collect(Vector3Stamped, '/accuracy/position_error',
                                              STREAM_QOS)
        self.orientation_errors = client.collect(Vector3Stamped, '/accuracy/orientation_error',
                                                 STREAM_QOS)
        self.diagnostics = client.collect(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self.pub_diag = node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self.rng = np.random.default_rng(7)
        self.now = 1_000_000_000_000  # ns
        self.clear()
        self.last_p, self.last_rv = HOME, np.zeros(3)

    def clear(self) -> None:
        self.targets: list[tuple[float, Any, Any]] = []
        self.ends: list[float] = []
        self.meas: list[tuple[float, Any, Any]] = []
        self.truth: list[tuple[float, Any, Any]] = []

    def report(self) -> dict[str, Any]:
        response = self.client.call(Trigger, '/accuracy_monitor/report', Trigger.Request())
        assert response.success
        return dict(json.loads(response.message))

    def visit(self, name: str, offset: Any = None) -> None:
        """Command pose ``name``, wait until the node has it, then stream the approach and the
        rest at ``offset`` (default OFFSETS[name]), measured and true, with the positioner's
        move end (its ``settled`` status) when the approach is over, waiting until the node has
        taken them all."""
        goal_p, goal_rv = POSES[name]
        goal_q = Rotation.from_rotvec(goal_rv).as_quat()
        self.now += 20_000_000
        t0 = acc.stamp_seconds(self.now // 10**9, self.now % 10**9)
        self.pub_target.publish(pose_stamped(goal_p, goal_q, stamp(self.now)))
        self.targets.append((t0, np.array(goal_p), goal_q))
        wait_until(lambda: (self.report()['target'] or {}).get('time') == t0, 15.0,
                   f'the node to take target {name}')
        expected = len(self.position_errors)
        offset = OFFSETS[name] if offset is None else offset
        true_goal = goal_p + offset - TRACKER_BIAS
        for k in range(1, int(VISIT * RATE) + 1):
            self.now += int(1e9 / RATE)
            t = acc.stamp_seconds(self.now // 10**9, self.now % 10**9)
            s = min(k / (0.3 * RATE), 1.0)
            p_true = self.last_p + s * (true_goal - self.last_p)
            rv_true = self.last_rv + s * (np.asarray(goal_rv) - self.last_rv)
            q_true = Rotation.from_rotvec(rv_true).as_quat()
            p_meas = p_true + TRACKER_BIAS + self.rng.normal(0.0, 3e-6, 3)
            q_meas = Rotation.from_rotvec(rv_true + self.rng.normal(0.0, 1e-5, 3)).as_quat()
            self.pub_truth.publish(pose_stamped(p_true, q_true, stamp(self.now)))
            msg = PoseWithCovarianceStamped()
            msg.header.stamp, msg.header.frame_id = stamp(self.now), 'base'
            msg.pose.pose = pose_msg(p_meas, q_meas)
            msg.pose.covariance = STATED.ravel().tolist()
            self.pub_meas.publish(msg)
            self.truth.append((t, p_true, q_true))
            self.meas.append((t, p_meas, q_meas))
            expected += 1
            if k == int(0.3 * RATE):  # arrived: the positioner reports the move's end
                self.pub_diag.publish(diagnostic(
                    names.STATUS_POSITIONER, 'ok', 'settled: there',
                    {'state': 'settled', 'code': 'success', 'mode': 'model'}, stamp(self.now)))
                self.ends.append(t)
                wait_until(lambda e=t: (self.report()['target'] or {}).get('move_end') == e,
                           15.0, 'the node to take the move end')
            if k % 20 == 0:  # pace: the node has taken every measurement so far
                wait_until(lambda n=expected: len(self.position_errors) >= n, 15.0,
                           'the position errors')
        self.last_p, self.last_rv = true_goal, np.asarray(goal_rv)
        pairs = len(self.meas)
        wait_until(lambda: (self.report()['tracker'] or {}).get('samples') == pairs, 15.0,
                   'every measurement paired with its truth')

    def batch(self, series: list[tuple[float, Any, Any]]) -> acc.AccuracyResult:
        """The library's batch analysis of what was sent."""
        t, p, q = (np.array(x) for x in zip(*series, strict=True))
        tt, tp, tq = (np.array(x) for x in zip(*self.targets, strict=True))
        return acc.analyse(t, p, q, tt, tp, tq, settings(),
                           end_times=[e for e in self.ends if e >= tt[0]])


def set_parameter(client: Client, name: str, value: float) -> Any:
    return client.set_parameter('accuracy_monitor', name, value)


def get_parameter(client: Client, name: str) -> float:
    response = client.call(GetParameters, '/accuracy_monitor/get_parameters',
                           GetParameters.Request(names=[name]))
    return float(response.values[0].double_value)


def statuses(cell: Cell, name: str) -> list[DiagnosticStatus]:
    return [s for a in list(cell.diagnostics) for s in a.status if s.name == name]


def jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value))


@pytest.fixture(scope='module')
def visited() -> Iterator[Cell]:
    """One monitor fed four visits (A, B, A, B) with the tracker's and the truth's samples,
    shared by the cases below (read-only but the last, which resets it)."""
    with in_process() as ros:
        client = ros.client
        ros.start(AccuracyMonitorNode)
        cell = Cell(client)
        node = client.node
        wait_until(lambda: (cell.pub_meas.get_subscription_count() > 0
                            and cell.pub_target.get_subscription_count() > 0
                            and cell.pub_truth.get_subscription_count() > 0
                            and node.count_publishers('/accuracy/position_error') > 0
                            and node.count_publishers('/diagnostics') > 0), 20.0,
                   'discovery of accuracy_monitor')
        assert cell.report()['target'] is None
        # The monitor's own view: every input has matched this client's publisher.
        inputs = ('/positioner/target', '/metrology/pose', '/sim/platform/true_pose')
        wait_until(lambda: all(cell.report()['publishers'][t] == 1 for t in inputs), 20.0,
                   'the monitor to match the three input publishers')
        for name in ('A', 'B', 'A', 'B'):
            cell.visit(name)
        wait_until(lambda: len(cell.orientation_errors) >= len(cell.meas), 10.0,
                   'the orientation errors')
        yield cell


def test_one_error_per_measurement_as_the_library_computes_it(visited: Cell) -> None:
    cell = visited
    assert len(cell.position_errors) == len(cell.meas)
    t, p, q = (np.array(x) for x in zip(*cell.meas, strict=True))
    tt, tp, tq = (np.array(x) for x in zip(*cell.targets, strict=True))
    seg = np.searchsorted(tt, t, side='right') - 1
    dp, rv = acc.measurement_error(p, q, tp[seg], tq[seg])
    got_dp = [[m.vector.x, m.vector.y, m.vector.z] for m in cell.position_errors]
    got_rv = [[m.vector.x, m.vector.y, m.vector.z] for m in cell.orientation_errors]
    np.testing.assert_allclose(got_dp, dp, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got_rv, rv, rtol=0, atol=1e-15)
    assert all(m.header.frame_id == 'base' for m in cell.position_errors)
    # At rest the position error is the offset (noise 3 µm per axis).
    np.testing.assert_allclose(got_dp[-1], OFFSETS['B'], atol=15e-6)


def test_one_verdict_per_settled_pose(visited: Cell) -> None:
    """A (30 µm) conforms, B (80 µm) does not, each by more than the U (k = 2) of its
    window's mean reading, which the tracker's stated covariance gives (ISO 14253-1)."""
    verdicts = wait_until(lambda: (v := statuses(visited, 'accuracy_monitor: settled pose'))
                          and len(v) >= 4 and v, 10.0, 'four verdicts')
    assert [s.level for s in verdicts] == [DiagnosticStatus.OK, DiagnosticStatus.ERROR] * 2
    assert 'pose 1 cycle 2' in verdicts[3].message and 'µm' in verdicts[3].message
    values = {kv.key: kv.value for kv in verdicts[3].values}
    assert float(values['position_error_um']) == pytest.approx(80.0, abs=10.0)
    assert values['n'] == '2' and values['RP_l_um'] != 'n/a'
    decided = [{kv.key: kv.value for kv in s.values} for s in verdicts]
    assert [d['decision'] for d in decided] == ['conforms', 'does not conform'] * 2
    assert all(d['decision_rule'] == 'iso_14253_1' for d in decided)
    # one reading's 3 µm per axis, averaged down over the window: under 2 x 3 µm x sqrt(3)
    assert all(0.0 < float(d['position_uncertainty_um']) < 10.4 for d in decided)
    # each visit's own stabilisation time and overshoot (ISO 9283 7.4, 7.5) beside its figures
    assert all({'stabilisation_time', 'overshoot', 'stabilisation_resolved',
                'path_deviation'} <= d.keys() for d in decided)


def test_the_report_is_the_librarys_batch_computation(visited: Cell) -> None:
    cell = visited
    wait_until(lambda: len(statuses(cell, 'accuracy_monitor: settled pose')) >= 4, 10.0,
               'four verdicts')
    report = cell.report()
    batch = cell.batch(cell.meas)
    assert [(v.key, v.cycle) for v in batch.visits] == [(0, 1), (1, 1), (0, 2), (1, 2)]
    assert report['measured'] == jsonable(batch.to_dict())
    assert report['verdicts'] == {'ok': 2, 'error': 2}
    assert report['decisions'] == {'conforms': 2, 'indeterminate': 0, 'does_not_conform': 2}
    assert report['truth'] == jsonable(cell.batch(cell.truth).to_dict())
    tm, pm, qm = (np.array(x) for x in zip(*cell.meas, strict=True))
    tt_, pt, qt = (np.array(x) for x in zip(*cell.truth, strict=True))
    tracker = acc.tracker_errors(tm, pm, qm, tt_, pt, qt, 1e-3)
    assert tracker is not None
    expected = jsonable(tracker.to_dict())  # the node's running sums: equal but for last bits
    assert report['tracker'].keys() == expected.keys()
    assert report['tracker']['samples'] == expected['samples']
    for key in ('mean_position_error', 'rms_position_error', 'max_position_error',
                'rms_orientation_error', 'max_orientation_error'):
        np.testing.assert_allclose(report['tracker'][key], expected[key], rtol=1e-12,
                                   atol=1e-20)
    np.testing.assert_allclose(report['tracker']['mean_position_error'], TRACKER_BIAS,
                               atol=2e-6)
    truth_b = next(f for f in report['truth']['poses'] if f['key'] == 1)
    assert truth_b['ap_p'] == pytest.approx(
        float(np.linalg.norm(OFFSETS['B'] - TRACKER_BIAS)), rel=1e-6)


def test_a_bad_message_is_refused_with_a_reason_and_the_node_runs_on(visited: Cell) -> None:
    bad = PoseWithCovarianceStamped()
    bad.header.frame_id = 'tracker'
    bad.pose.pose.orientation.w = 1.0
    visited.pub_meas.publish(bad)
    warning = wait_until(lambda: statuses(visited, 'accuracy_monitor: input'), 10.0,
                         'the bad-input warning')
    assert warning[0].level == DiagnosticStatus.WARN and "'tracker'" in warning[0].message
    assert visited.report()['verdicts'] == {'ok': 2, 'error': 2}  # nothing counted


def test_reset_and_tolerances_then_the_figures_again(visited: Cell) -> None:
    """Last (it resets the shared monitor): the reset clears the figures but keeps the
    current target; tolerances are validated dynamic parameters; then B's 80 µm offset passes
    the wider tolerance and the figures again equal the batch."""
    cell, client = visited, visited.client
    wait_until(lambda: len(statuses(cell, 'accuracy_monitor: settled pose')) >= 4, 10.0,
               'four verdicts')
    response = client.call(Trigger, '/accuracy_monitor/reset', Trigger.Request())
    assert response.success
    report = cell.report()
    assert report['measured'] == {'visits': [], 'poses': []}
    assert report['verdicts'] == {'ok': 0, 'error': 0}
    assert report['truth'] is None and report['tracker'] is None
    assert report['target']['time'] == cell.targets[-1][0]

    refused = set_parameter(client, 'tolerance.position', -1e-5)
    assert not refused.successful and refused.reason
    refused = set_parameter(client, 'settle.window', 2.0)
    assert not refused.successful and 'read-only' in refused.reason.lower()
    assert get_parameter(client, 'tolerance.position') == 5e-5
    assert set_parameter(client, 'tolerance.position', 1e-4).successful
    assert cell.report()['tolerances']['position'] == 1e-4

    # After the reset: B is key 0 (kept target), the new visit to A is key 1.
    cell.targets, cell.meas, cell.truth, cell.ends = cell.targets[-1:], [], [], []
    cell.visit('A', offset=OFFSETS['B'])
    verdicts = wait_until(lambda: (v := statuses(cell, 'accuracy_monitor: settled pose'))
                          and len(v) >= 5 and v, 10.0, 'the fifth verdict')
    assert verdicts[4].level == DiagnosticStatus.OK
    assert 'pose 1 cycle 1' in verdicts[4].message
    assert cell.report()['measured'] == jsonable(cell.batch(cell.meas).to_dict())


def test_the_monitor_tells_when_recording_stopped(ros: InProcess) -> None:
    """The monitor reads the recorder's status (here the test's) through the library's rule:
    nothing before a recorder is heard of; its state while it records; recording stopped,
    with the reason, in the report and in the monitor's own status when it fails or falls
    silent."""
    client = ros.client
    ros.start(AccuracyMonitorNode)
    diagnostics = client.collect(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
    pub = client.node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)

    def report() -> Any:
        response = client.call(Trigger, '/accuracy_monitor/report', Trigger.Request())
        return json.loads(response.message)['recording']

    def recorder(level: str, message: str, state: str) -> None:
        pub.publish(diagnostic('recorder', level, message, {'state': state},
                               client.node.get_clock().now().to_msg()))

    def told(level: int) -> list[DiagnosticStatus]:
        return [s for a in list(diagnostics) for s in a.status
                if s.name == 'accuracy_monitor: recording' and status_level(s) == level]

    assert report() is None
    wait_until(lambda: recorder('ok', 'recording', 'recording') or report(), 10.0,
               'the monitor to hear the recorder')
    assert report() == {'level': 0, 'message': 'recording', 'stopped': False}
    failure = ('recording stopped: ENOSPC (No space left on device) on write of '
               '/runs/x/bag/bag_0.mcap; bag closed with 1234 messages, 0 lost')
    recorder('error', failure, 'failed')
    wait_until(lambda: report()['stopped'], 10.0, 'the monitor to see the failure')
    assert report() == {'level': 2, 'message': failure, 'stopped': True}
    assert wait_until(lambda: told(2), 10.0, "the monitor's status")[0].message == failure

    # A recorder again, which then falls silent: recording stopped after SILENT_AFTER_S.
    wait_until(lambda: recorder('ok', 'recording', 'recording') or not report()['stopped'],
               10.0, 'the monitor to hear the recorder again')
    silent = wait_until(lambda: (r := report())['stopped'] and r, SILENT_AFTER_S + 10.0,
                        'the monitor to find the recorder silent')
    assert silent['level'] == 2
    assert silent['message'].startswith('recording stopped: recorder silent since ')
    wait_until(lambda: any(s.message == silent['message'] for s in told(2)), 10.0,
               "the monitor's status on the silence")


def test_a_target_that_comes_after_readings_stamped_after_it_applies_to_them(
        ros: InProcess) -> None:
    """Messages of different topics taken in stamp order, not arrival order: a target B
    published after the tracker's readings stamped 0.02-0.2 s after it (a datagram repaired
    late, a tracker's latency) still applies to them, as in the offline analysis of the same
    messages; in arrival order they were errors against the target A before it."""
    client = ros.client
    ros.start(AccuracyMonitorNode)
    cell = Cell(client)
    inputs = ('/positioner/target', '/metrology/pose')
    wait_until(lambda: (all(cell.report()['publishers'][t] == 1 for t in inputs)
                        and cell.pub_meas.get_subscription_count() > 0
                        and client.node.count_publishers('/accuracy/position_error') > 0), 20.0,
               'the monitor and this client to match each other')
    t0 = 1_000_000_000_000

    def target(name: str, ns: int) -> None:
        p, rv = POSES[name]
        cell.pub_target.publish(pose_stamped(p, Rotation.from_rotvec(rv).as_quat(),
                                             stamp(ns)))

    def reading(ns: int, p: Any) -> None:
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = stamp(ns), 'base'
        msg.pose.pose = pose_msg(p, [0.0, 0.0, 0.0, 1.0])
        msg.pose.covariance = STATED.ravel().tolist()
        cell.pub_meas.publish(msg)

    target('A', t0)
    wait_until(lambda: (cell.report()['target'] or {}).get('key') == 0, 15.0,
               'the node to take target A')  # (latched, one deep: B would replace it)
    for k in range(1, 11):  # readings at A, then readings stamped after B's target
        reading(t0 + k * 20_000_000, POSES['A'][0])
    target('B', t0 + 180_000_000)  # stamped before the last one, published after it
    for k in range(11, 80):
        reading(t0 + k * 20_000_000, POSES['B'][0])
    got = wait_until(lambda: len(cell.position_errors) >= 79 and list(cell.position_errors),
                     15.0, 'an error for every reading')
    by_stamp = {(e.header.stamp.sec, e.header.stamp.nanosec): np.array(
        [e.vector.x, e.vector.y, e.vector.z]) for e in got}
    a_to_b = POSES['B'][0] - POSES['A'][0]
    for k in range(1, 80):
        ns = t0 + k * 20_000_000
        error = by_stamp[(ns // 10**9, ns % 10**9)]
        # against A until B's stamp (0.18 s), then against B
        expected = np.zeros(3) if k < 9 else (-a_to_b if k < 11 else np.zeros(3))
        np.testing.assert_allclose(error, expected, atol=1e-9, err_msg=f'reading {k}')
    assert cell.report()['inputs']['late'] == 0
