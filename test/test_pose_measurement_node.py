"""The pose_measurement node in the test process: truth from joint states, the tracker located
on the base targets and its poses with covariance (judged against the truth), re-locating,
diagnostics, and validated dynamic parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from cell_harness import CELL_YAML, Client, InProcess, wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rcl_interfaces.srv import GetParameters
from scipy import stats
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.nodes.pose_measurement_node import PoseMeasurementNode
from positioning_cell.parameters import parse
from positioning_cell.ros.messages import joint_state, pose_arrays
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, STREAM_QOS
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings

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


def test_pose_measurement_node(ros: InProcess) -> None:
    params = node_parameters(load_parameter_file(CELL_YAML), NODE)
    mech = Mechanism.from_params(params['mechanism'])
    home = inverse(mech, mech.home_position, mech.home_quaternion)
    truth_machine = parse(PoseMeasurementSettings, params).true_machine()
    expected = truth_machine.poses(home.lengths, home.thetas)
    stamp = Time(sec=1234, nanosec=5678)

    client = ros.client
    ros.start(PoseMeasurementNode)
    true_poses = client.collect(PoseStamped, '/sim/platform/true_pose', STREAM_QOS)
    measured = client.collect(PoseWithCovarianceStamped, '/metrology/pose', STREAM_QOS)
    diagnostics = client.collect(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
    joints = client.node.create_publisher(JointState, '/sim/legs/true_joint_states',
                                          STREAM_QOS)
    wait_until(lambda: joints.get_subscription_count() > 0, 30, 'the node subscribing')

    # A malformed joint state is reported, not fatal, and yields no pose.
    joints.publish(joint_state(JOINT_NAMES[:5], stamp, [0.2] * 5))
    wait_until(lambda: any('ignored a true joint state' in s.message
                           and s.level == DiagnosticStatus.WARN
                           for s in statuses(diagnostics)), 15, 'the warning')
    assert not true_poses

    joints.publish(joint_state(JOINT_NAMES, stamp, [*home.lengths[0], *home.thetas[0]]))
    wait_until(lambda: true_poses and len(measured) >= 10, 30, 'true and measured poses')

    truth = true_poses[0]
    assert truth.header.frame_id == 'base' and truth.header.stamp == stamp
    p_true, q_true = pose_arrays(truth.pose)
    np.testing.assert_allclose(p_true, expected.position[0], atol=1e-12)
    np.testing.assert_allclose(q_true, expected.quaternion[0], atol=1e-12)
    assert np.linalg.norm(p_true - mech.home_position) > 10e-6  # the clearance shows

    bound = stats.chi2.ppf(1.0 - 1e-6, 6)
    samples = []
    for msg in list(measured)[:10]:
        assert msg.header.frame_id == 'base' and msg.header.stamp == stamp
        p, q = pose_arrays(msg.pose.pose)
        cov = np.asarray(msg.pose.covariance).reshape(6, 6)
        np.testing.assert_allclose(cov, cov.T, rtol=1e-12, atol=0.0)
        np.linalg.cholesky(cov)  # positive definite
        rot = Rotation.from_quat(q) * Rotation.from_quat(q_true).inv()
        err = np.hstack([p - p_true, rot.as_rotvec()])
        assert err @ np.linalg.solve(cov, err) < bound
        samples.append(err)
    assert np.ptp(np.asarray(samples), axis=0).min() > 0.0  # fresh noise each reading
    wait_until(lambda: any(s.level == DiagnosticStatus.OK
                           and {v.key: v.value for v in s.values}.get('targets_used') == '5'
                           for s in statuses(diagnostics)), 15, 'an OK diagnostic')
    # The registration the node located itself with, and its residuals, on /diagnostics.
    values = {v.key: v.value for v in statuses(diagnostics)[-1].values}
    assert values['locations'] == '1'
    located = np.asarray(json.loads(values['located_position']))
    true_position = np.asarray(params['truth']['tracker']['position'])
    assert 0.0 < np.linalg.norm(located - true_position) < 1e-4  # located, not given
    residuals = json.loads(values['locate_residuals_um'])
    assert len(residuals) == len(params['locate']['base_targets']) // 3
    assert 0.0 < float(values['locate_residual_rms_um']) < 20.0

    # Re-locating: a fresh registration, reported in the answer and on /diagnostics.
    response = client.call(Trigger, names.LOCATE_TRACKER, Trigger.Request())
    assert response.success and 'tracker located on 6/6 base targets' in response.message
    wait_until(lambda: any({v.key: v.value for v in s.values}.get('locations') == '2'
                           for s in statuses(diagnostics)), 15, 'the new location reported')

    # Dynamic parameters: a bad value is refused with a reason and the old one stays.
    ok, reason = set_parameter(client, 'fault.occlusion_probability', 1.5)
    assert not ok and reason
    assert get_double(client, 'fault.occlusion_probability') == 0.0
    ok, reason = set_parameter(client, 'targets.platform', [0.1, 0.0, 0.0, 0.0, 0.1, 0.0])
    assert not ok and 'targets.platform = ' in reason and 'at least 4' in reason
    ok, reason = set_parameter(client, 'truth.clearance.seed', 3)
    assert not ok and reason
    ok, reason = set_parameter(client, 'truth.tracker.scale_ppm', 0.0)
    assert not ok and reason  # the truth is read-only
    ok, reason = set_parameter(client, 'fault.outlier_probability', 0.25)
    assert ok, reason
    assert get_double(client, 'fault.outlier_probability') == 0.25
