"""The pose_measurement node in the test process: truth from joint states, the tracker located
on the base targets and its poses with covariance (judged against the truth), re-locating,
diagnostics, and validated dynamic parameters."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from cell_harness import CELL_YAML, Client, InProcess, in_process, wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from rcl_interfaces.srv import GetParameters
from scipy import stats
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState, Temperature
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.nodes.pose_measurement_node import PoseMeasurementNode
from positioning_cell.parameters import parse
from positioning_cell.ros import messages as m
from positioning_cell.ros.messages import joint_state, pose_arrays, registration
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, STREAM_QOS
from positioning_cell.sim.pose_measurement import TARGETS_PREFIX, PoseMeasurementSettings

pytestmark = pytest.mark.nodes

NODE = 'pose_measurement'


def set_parameter(client: Client, name: str, value: object) -> tuple[bool, str]:
    result = client.set_parameter(NODE, name, value)
    return result.successful, result.reason


def get_double(client: Client, name: str) -> float:
    response = client.call(GetParameters, f'/{NODE}/get_parameters',
                           GetParameters.Request(names=[name]))
    return float(response.values[0].double_value)


def statuses(diagnostics: list[DiagnosticArray]) -> list[DiagnosticStatus]:
    return [s for array in list(diagnostics) for s in array.status if s.name == NODE]


@dataclass
class Run:
    """One pose_measurement node fed a malformed joint state, then the home pose: what it
    published, and the expected truth."""

    ros: InProcess
    params: dict[str, Any]
    mech: Mechanism
    expected: Any
    stamp: Time
    true_poses: list[PoseStamped]
    measured: list[PoseWithCovarianceStamped]
    air: list[Temperature]
    diagnostics: list[DiagnosticArray]
    registrations: list[PoseWithCovarianceStamped]
    poses_before_home: int  # true poses after the malformed joint state


@pytest.fixture(scope='module')
def run() -> Iterator[Run]:
    """The node, shared by this module's cases (each reads what it needs; the cases that
    change it come last)."""
    params = node_parameters(load_parameter_file(CELL_YAML), NODE)
    mech = Mechanism.from_params(params['mechanism'])
    home = inverse(mech, mech.home_position, mech.home_quaternion)
    truth_machine = parse(PoseMeasurementSettings, params).true_machine()
    # The machine's conditions at its first joint state: the start of its history.
    history = truth_machine.history()
    history.update(np.r_[home.lengths[0], home.thetas[0]], 0.0)
    expected = truth_machine.poses(home.lengths, home.thetas,
                                   conditions=history.conditions(0.0))
    stamp = Time(sec=1234, nanosec=5678)
    with in_process() as ros:
        client = ros.client
        ros.start(PoseMeasurementNode)
        true_poses = client.collect(PoseStamped, '/sim/platform/true_pose', STREAM_QOS)
        measured = client.collect(PoseWithCovarianceStamped, '/metrology/pose', STREAM_QOS)
        air = client.collect(Temperature, '/cell/air_temperature', STREAM_QOS)
        diagnostics = client.collect(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        # latched: taken although the node published it before this subscription
        registrations = client.collect(PoseWithCovarianceStamped, names.TRACKER_REGISTRATION,
                                       LATCHED_QOS)
        joints = client.node.create_publisher(JointState, '/sim/legs/true_joint_states',
                                              STREAM_QOS)
        wait_until(lambda: joints.get_subscription_count() > 0, 30, 'the node subscribing')
        # A malformed joint state first (test_a_malformed_joint_state_is_reported), then home.
        joints.publish(joint_state(JOINT_NAMES[:5], stamp, [0.2] * 5))
        wait_until(lambda: any('ignored a true joint state' in s.message
                               and s.level == DiagnosticStatus.WARN
                               for s in statuses(diagnostics)), 15, 'the warning')
        before_home = len(true_poses)
        joints.publish(joint_state(JOINT_NAMES, stamp, [*home.lengths[0], *home.thetas[0]]))
        wait_until(lambda: true_poses and len(measured) >= 10, 30, 'true and measured poses')
        wait_until(lambda: len(air) >= 2, 30, 'air temperatures')
        yield Run(ros, params, mech, expected, stamp, true_poses, measured, air, diagnostics,
                  registrations, before_home)


def test_a_malformed_joint_state_is_reported_and_yields_no_pose(run: Run) -> None:
    assert any('ignored a true joint state' in s.message and s.level == DiagnosticStatus.WARN
               for s in statuses(run.diagnostics))
    assert run.poses_before_home == 0


def test_the_true_pose_is_the_true_machines_with_its_clearance(run: Run) -> None:
    truth = run.true_poses[0]
    assert truth.header.frame_id == 'base' and truth.header.stamp == run.stamp
    p_true, q_true = pose_arrays(truth.pose)
    # The node's clock starts with its first timer or joint state, a few seconds before the
    # home joints: the air drifts by < 0.01 K meanwhile, moving the machine by < 1e-10 m.
    np.testing.assert_allclose(p_true, run.expected.position[0], atol=1e-10)
    np.testing.assert_allclose(q_true, run.expected.quaternion[0], atol=1e-9)
    assert np.linalg.norm(p_true - run.mech.home_position) > 10e-6  # the clearance shows


def test_the_air_temperature_is_the_sensors_reading(run: Run) -> None:
    thermal = run.params['truth']['thermal']
    variance = thermal['sensor_offset_sigma']**2 + thermal['sensor_noise']**2
    first, second = list(run.air)[:2]
    for msg in (first, second):
        assert msg.header.frame_id == 'base'
        assert msg.variance == pytest.approx(variance, rel=1e-12)
        # air_start plus a few seconds of drift and noise, plus the sensor's error
        assert abs(msg.temperature - thermal['air_start']) < 5 * thermal['air_noise'] + 0.5
    assert first.temperature != second.temperature  # fresh noise


def test_measurements_are_fresh_noise_within_their_covariance(run: Run) -> None:
    p_true, q_true = pose_arrays(run.true_poses[0].pose)
    bound = stats.chi2.ppf(1.0 - 1e-6, 6)
    samples = []
    for msg in list(run.measured)[:10]:
        assert msg.header.frame_id == 'base' and msg.header.stamp == run.stamp
        p, q = pose_arrays(msg.pose.pose)
        cov = np.asarray(msg.pose.covariance).reshape(6, 6)
        np.testing.assert_allclose(cov, cov.T, rtol=1e-12, atol=0.0)
        np.linalg.cholesky(cov)  # positive definite
        rot = Rotation.from_quat(q) * Rotation.from_quat(q_true).inv()
        err = np.hstack([p - p_true, rot.as_rotvec()])
        assert err @ np.linalg.solve(cov, err) < bound
        samples.append(err)
    assert np.ptp(np.asarray(samples), axis=0).min() > 0.0  # fresh noise each reading


def test_the_registration_and_its_residuals_are_on_diagnostics(run: Run) -> None:
    ok = wait_until(lambda: [s for s in statuses(run.diagnostics) if s.level ==
                             DiagnosticStatus.OK and {v.key: v.value for v in s.values}
                             .get('targets_used') == '5'], 15, 'an OK diagnostic')
    values = {v.key: v.value for v in ok[-1].values}
    assert values['locations'] == '1'
    located = np.asarray(json.loads(values['located_position']))
    true_position = np.asarray(run.params['truth']['tracker']['position'])
    assert 0.0 < np.linalg.norm(located - true_position) < 1e-4  # located, not given
    residuals = json.loads(values['locate_residuals_um'])
    assert len(residuals) == len(run.params['locate']['base_targets']) // 3
    assert 0.0 < float(values['locate_residual_rms_um']) < 20.0


def test_the_registration_is_published_and_common_to_every_reading(run: Run) -> None:
    """/metrology/registration, latched: the located tracker (near its true pose, not at it)
    and its covariance, which every reading's covariance holds (reading − registration at
    the reading's pose is positive semi-definite and not zero: the reading's own noise)."""
    msgs = wait_until(lambda: list(run.registrations), 15, 'the registration')
    located = registration(msgs[0])
    true_position = np.asarray(run.params['truth']['tracker']['position'])
    assert msgs[0].header.frame_id == 'base'
    assert 0.0 < np.linalg.norm(located.position - true_position) < 1e-4
    assert np.linalg.eigvalsh(located.covariance).min() > 0.0
    for reading in list(run.measured)[:5]:
        p, _ = pose_arrays(reading.pose.pose)
        own = (np.asarray(reading.pose.covariance).reshape(6, 6)
               - located.covariance_at(p)[0])
        eig = np.linalg.eigvalsh(0.5 * (own + own.T))
        assert eig.min() >= -1e-9 * eig.max() and eig.max() > 0.0


def test_relocating_gives_a_fresh_registration(run: Run) -> None:
    response = run.ros.client.call(Trigger, names.LOCATE_TRACKER, Trigger.Request())
    assert response.success and 'tracker located on 6/6 base targets' in response.message
    wait_until(lambda: any({v.key: v.value for v in s.values}.get('locations') == '2'
                           for s in statuses(run.diagnostics)), 15, 'the new location reported')
    wait_until(lambda: len(run.registrations) >= 2, 15, 'the new registration published')
    first, second = (registration(msg) for msg in list(run.registrations)[:2])
    assert np.any(first.position != second.position)  # fresh readings of the base targets


@pytest.mark.parametrize(('name', 'value', 'words'), [
    ('fault.occlusion_probability', 1.5, ''),
    (f'{TARGETS_PREFIX}platform', [0.1, 0.0, 0.0, 0.0, 0.1, 0.0], 'at least 4'),
    ('truth.clearance.seed', 3, ''),
    ('truth.tracker.scale_ppm', 0.0, ''),  # the truth is read-only
])
def test_a_bad_or_read_only_parameter_is_refused_with_a_reason(run: Run, name: str,
                                                              value: object,
                                                              words: str) -> None:
    ok, reason = set_parameter(run.ros.client, name, value)
    assert not ok and reason and words in reason, reason
    if name == 'fault.occlusion_probability':
        assert get_double(run.ros.client, name) == 0.0  # the old value stays
    if words:
        assert f'{name} = ' in reason


def test_a_good_parameter_is_taken(run: Run) -> None:
    ok, reason = set_parameter(run.ros.client, 'fault.outlier_probability', 0.25)
    assert ok, reason
    assert get_double(run.ros.client, 'fault.outlier_probability') == 0.25


def test_the_load_rig_applies_its_command_and_refuses_a_bad_one(run: Run) -> None:
    """/load_rig/force reads zero at start (latched); a command in base is applied and read
    back, and the true pose of the same joints, stamped anew, yields to it; a command in
    another frame or with a torque is refused and changes nothing."""
    client = run.ros.client
    forces = client.collect(WrenchStamped, names.LOAD_FORCE, LATCHED_QOS)
    wait_until(lambda: forces, 15, 'the rig\'s reading at start')
    assert m.force_of(forces[0]).tolist() == [0.0, 0.0, 0.0]
    command = client.node.create_publisher(WrenchStamped, names.LOAD_COMMAND, LATCHED_QOS)
    joints = client.node.create_publisher(JointState, names.TRUE_JOINT_STATES, STREAM_QOS)
    home = inverse(run.mech, run.mech.home_position, run.mech.home_quaternion)
    before = pose_arrays(run.true_poses[-1].pose)[0]
    command.publish(m.force_stamped([0.0, 40.0, 0.0], Time()))
    wait_until(lambda: m.force_of(forces[-1]).tolist() == [0.0, 40.0, 0.0], 15, 'the load read')
    stamp = Time(sec=2000)
    wait_until(lambda: joints.get_subscription_count() > 0, 15, 'the node subscribing')
    joints.publish(joint_state(JOINT_NAMES, stamp, [*home.lengths[0], *home.thetas[0]]))
    wait_until(lambda: run.true_poses[-1].header.stamp == stamp, 15, 'the loaded true pose')
    moved = pose_arrays(run.true_poses[-1].pose)[0] - before
    assert 20e-6 < moved[1] < 100e-6  # this machine yields ~1 µm/N across its axis
    count = len(forces)
    bad = m.force_stamped([0.0, 10.0, 0.0], Time(), frame='platform')
    torque = m.force_stamped([0.0, 10.0, 0.0], Time())
    torque.wrench.torque.x = 1.0
    for msg in (bad, torque):
        command.publish(msg)
    command.publish(m.force_stamped([0.0, 0.0, 0.0], Time()))
    wait_until(lambda: len(forces) > count, 15, 'the unload read')
    assert [m.force_of(f).tolist() for f in list(forces)[count:]] == [[0.0, 0.0, 0.0]]
