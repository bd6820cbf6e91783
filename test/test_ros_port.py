"""The procedures' port on a live cell (positioning_cell.ros.port.RosCellPort): what it reads
of the encoders is the encoders now, not what its subscription kept from before."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from cell_harness import InProcess, wait_until
from rclpy.node import Node
from sensor_msgs.msg import JointState

from positioning_cell import names
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.ros.messages import joint_state, stamp
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.qos import STREAM_QOS

pytestmark = pytest.mark.nodes


def test_the_joints_are_a_reading_stamped_after_the_call(ros: InProcess) -> None:
    """A reading stamped before the call (what a lagging subscription holds after a jog) is
    not the answer: the port waits for one stamped from the call on; with none, it says so
    (an axis test once planned a jog from a reading 0.3 s old and ended 177 µm off)."""
    drives = Node('fake_drives', context=ros.context)
    try:
        pub = drives.create_publisher(JointState, names.JOINT_STATES, STREAM_QOS)
        port = RosCellPort(ros.client, timeout=0.5)
        wait_until(lambda: pub.get_subscription_count() > 0, 10.0, 'the port subscribed')
        old, now = np.full(6, 0.1), np.full(6, 0.2)
        pub.publish(joint_state(JOINT_NAMES, stamp(time.time() - 1.0), old, np.zeros(6)))
        wait_until(lambda: bool(port._joints), 10.0, 'the old reading at the port')
        with pytest.raises(ProcedureError, match='an encoder reading on /legs/joint_states'):
            port.joints()  # the old reading alone: none from the call on
        port.timeout = 10.0
        got: list[np.ndarray] = []
        asking = threading.Thread(target=lambda: got.append(port.joints()))
        asking.start()
        while asking.is_alive():  # the first reading stamped after its call answers it
            pub.publish(joint_state(JOINT_NAMES, stamp(time.time()), now, np.zeros(6)))
            asking.join(0.05)
        np.testing.assert_array_equal(got[0], now)
    finally:
        drives.destroy_node()
