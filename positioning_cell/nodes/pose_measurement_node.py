"""pose_measurement_node (node ``pose_measurement``): the machine's truth and a simulated laser
tracker measuring it (:mod:`positioning_cell.sim.pose_measurement`).

At start the tracker locates itself on the base reference targets (``locate.*``; again on
/pose_measurement/locate), logs the registration and its residuals and publishes it, latched, on
/metrology/registration (the part of every reading's covariance common to all readings) and as
base → tracker on /tf_static. The newest
/sim/legs/true_joint_states → the true platform pose (at most ``truth_rate_hz``) on
/sim/platform/true_pose, stamped with the joint state's time → at ``rate_hz`` a tracker reading
of the SMRs, converted to ``base`` with the located registration, the fitted pose and the
cell's own covariance of it (datasheet noise and registration uncertainty) on /metrology/pose
and as base → platform_measured on /tf, stamped with the time of the truth it measured. At
``air_sensor.rate_hz`` the air-temperature sensor's reading on /cell/air_temperature (its
variance the sensor's own error). The compliance test's load rig: a force on /load_rig/command
(latched, frame ``base``) is applied to the machine and its load cell's reading published,
latched, on /load_rig/force (at start: no load); a command it cannot take is logged and
changes nothing.
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState, Temperature
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from positioning_cell import names
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import InputError
from positioning_cell.ros import messages as m
from positioning_cell.ros.latest import Reader
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import (
    DIAGNOSTICS_QOS,
    LATCHED_QOS,
    SERVICE_QOS,
    STREAM_QOS,
    TF_QOS,
)
from positioning_cell.ros.robot_state import frames_message
from positioning_cell.ros.spin import NodeStart
from positioning_cell.sim.pose_measurement import (
    PoseMeasurementSettings,
    PoseMeasurementSimulator,
)


class PoseMeasurementNode(Node):
    """The ``pose_measurement`` node (docs/conventions/interfaces.md)."""

    NAME = names.NODE_MEASUREMENT
    SETTINGS = PoseMeasurementSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS,
                                     lambda s, _: self.sim.reconfigure(s))
        settings = self.params.settings
        self.sim = PoseMeasurementSimulator(settings)
        self._registration_pub = self.create_publisher(
            PoseWithCovarianceStamped, names.TRACKER_REGISTRATION, LATCHED_QOS)
        self._tf_static_pub = self.create_publisher(TFMessage, names.TF_STATIC, LATCHED_QOS)
        self._tf_pub = self.create_publisher(TFMessage, names.TF, TF_QOS)
        self._log_location()
        self._joints = Reader(self, JointState, names.TRUE_JOINT_STATES)
        self._true_pub = self.create_publisher(PoseStamped, names.TRUE_POSE, STREAM_QOS)
        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                               STREAM_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)
        self._air_pub = self.create_publisher(Temperature, names.AIR_TEMPERATURE, STREAM_QOS)
        self.create_timer(1.0 / settings.truth_rate_hz, self._update_truth)
        self.create_timer(1.0 / settings.rate_hz, self._measure)
        self.create_timer(1.0, self._diagnostics)
        self.create_timer(1.0 / settings.air_sensor.rate_hz, self._air_temperature)
        self.create_service(Trigger, names.LOCATE_TRACKER, self._locate, qos_profile=SERVICE_QOS)
        self._force_pub = self.create_publisher(WrenchStamped, names.LOAD_FORCE, LATCHED_QOS)
        self._publish_force()
        self.create_subscription(WrenchStamped, names.LOAD_COMMAND, self._load, LATCHED_QOS)

    def _load(self, msg: WrenchStamped) -> None:
        try:
            self.sim.apply_load(m.force_of(msg))
        except InputError as err:
            self.get_logger().error(f'{names.LOAD_COMMAND}: {err}; the load stays '
                                    f'{self.sim.load.tolist()} N')
            return
        self._publish_force()

    def _publish_force(self) -> None:
        self._force_pub.publish(m.force_stamped(self.sim.load, self.get_clock().now().to_msg()))

    def _log_location(self) -> None:
        """Log the located registration and publish it (latched) on
        /metrology/registration."""
        location = self.sim.location
        covariance = None if location is None else location.tracker.covariance
        if location is not None and covariance is not None:
            tracker, now = location.tracker, self.get_clock().now().to_msg()
            self._registration_pub.publish(m.registration_msg(
                tracker.position, tracker.orientation, covariance, now))
            self._tf_static_pub.publish(frames_message(
                [(names.BASE_FRAME, names.TRACKER_FRAME, tracker.position, tracker.orientation)],
                now))
        level, message = self.sim.locate_status
        values = self.sim.location_values()
        if values:
            message += (f'; tracker at {values["located_position"]} m, orientation '
                        f'{values["located_orientation"]}, registration sigma '
                        f'{values["registration_sigma_position_um"]} um, '
                        f'{values["registration_sigma_rotation_urad"]} urad; residuals per '
                        f'target {values["locate_residuals_um"]} um')
        log = self.get_logger()
        (log.info if level == 'ok' else log.warning if level == 'warn' else log.error)(message)

    def _locate(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        response.success, response.message = self.sim.locate()
        self._log_location()
        self._diagnostics()
        return response

    def _update_truth(self) -> None:
        msg = self._joints.newest()
        if msg is not None:
            stamp, now = msg.header.stamp, self.get_clock().now().to_msg()
            # The effects' clock is the node's (the stamp is the truth's, opaque).
            self.sim.joints(m.joint_values(msg, JOINT_NAMES),
                            now if m.stamp_is_zero(stamp) else stamp, m.seconds(now))
        true = self.sim.update_truth()
        if true is not None:
            self._true_pub.publish(m.pose_stamped(true.position, true.quaternion, true.stamp))

    def _measure(self) -> None:
        reading = self.sim.measure()
        if reading is None:
            return
        self._pose_pub.publish(m.pose_with_covariance(
            reading.fit.position[0], reading.fit.quaternion[0], reading.fit.covariance[0],
            reading.stamp))
        self._tf_pub.publish(frames_message([(names.BASE_FRAME, names.PLATFORM_MEASURED_FRAME,
                                              reading.fit.position[0], reading.fit.quaternion[0])],
                                            reading.stamp))

    def _air_temperature(self) -> None:
        now = self.get_clock().now().to_msg()
        reading = self.sim.air_temperature(m.seconds(now))
        msg = Temperature()
        msg.header.stamp, msg.header.frame_id = now, names.BASE_FRAME
        msg.temperature, msg.variance = reading.temperature, reading.variance
        self._air_pub.publish(msg)

    def _diagnostics(self) -> None:
        level, message, values = self.sim.diagnostics()
        if level != 'ok':
            self.get_logger().warning(message)
        self._diag_pub.publish(m.diagnostic(names.STATUS_MEASUREMENT, level, message, values,
                                            self.get_clock().now().to_msg()))


#: The entry point of ``pose_measurement_node`` (alone; ``cell_container`` hosts it with others).
#: It imports no scipy as it spins: its truth, readings and fits are numpy (test_node_start).
main = NodeStart(PoseMeasurementNode, imports=())


if __name__ == '__main__':
    raise SystemExit(main())
