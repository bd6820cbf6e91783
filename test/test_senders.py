"""Messages taken with the node that sent them (positioning_cell.ros.senders, through rcl's
message info, which rclpy in Jazzy does not pass on), and the readers built on it: the
positioner's inputs from their source node only, a second publisher dropped and named."""

from __future__ import annotations

import pytest
from cell_harness import InProcess, wait_until
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory

from positioning_cell.ros.latest import SourceReader
from positioning_cell.ros.qos import COMMAND_QOS, JOINT_READER_QOS
from positioning_cell.ros.senders import GID_BYTES, IdentifiedSubscription, own_publisher_ids

pytestmark = pytest.mark.nodes


def test_each_message_is_taken_with_the_node_that_published_it(ros: InProcess) -> None:
    talker = Node('talker', namespace='/cell', context=ros.context)
    rogue = Node('rogue', context=ros.context)
    listener = Node('listener', context=ros.context)
    try:
        sub = IdentifiedSubscription(listener, JointTrajectory, '/commands', COMMAND_QOS)
        mine = talker.create_publisher(JointTrajectory, '/commands', COMMAND_QOS)
        theirs = rogue.create_publisher(JointTrajectory, '/commands', COMMAND_QOS)
        wait_until(lambda: sorted(sub.publishers()) == ['/cell/talker', '/rogue'], 10.0,
                   'both publishers in the graph')
        mine.publish(JointTrajectory(joint_names=['a']))
        theirs.publish(JointTrajectory(joint_names=['b', 'c']))
        taken: list = []
        wait_until(lambda: taken.extend(sub.take()) or len(taken) == 2, 10.0, 'two messages')
        by_sender = {t.sender: t.data for t in taken}
        assert set(by_sender) == {'/cell/talker', '/rogue'}
        assert b'a\x00' in by_sender['/cell/talker'] and b'c\x00' in by_sender['/rogue']
        assert sub.take() == []
        sub.destroy()
    finally:
        for node in (talker, rogue, listener):
            node.destroy_node()


def test_a_publisher_knows_the_gid_its_listeners_see_and_a_successor_gets_another(
        ros: InProcess) -> None:
    """What the positioner compares with the driver's status (``commander_publishers``): its
    own publisher's GID from its own graph is the one a listener's graph lists for it, and a
    publisher created anew under the same node name has another."""
    talker = Node('talker', context=ros.context)
    listener = Node('listener', context=ros.context)
    try:
        sub = IdentifiedSubscription(listener, JointTrajectory, '/commands', COMMAND_QOS)
        assert own_publisher_ids(talker, '/commands') == frozenset()
        first = talker.create_publisher(JointTrajectory, '/commands', COMMAND_QOS)
        mine = own_publisher_ids(talker, '/commands')
        assert len(mine) == 1 and len(next(iter(mine))) == 2 * GID_BYTES
        wait_until(lambda: {e.gid.hex() for e in sub.endpoints()} == mine, 10.0,
                   "the talker's publisher in the listener's graph")
        assert [e.node for e in sub.endpoints()] == ['/talker']
        talker.destroy_publisher(first)
        talker.create_publisher(JointTrajectory, '/commands', COMMAND_QOS)
        again = own_publisher_ids(talker, '/commands')
        assert len(again) == 1 and again != mine
        sub.destroy()
    finally:
        for node in (talker, listener):
            node.destroy_node()


def test_a_source_reader_takes_its_source_only_and_names_the_others(ros: InProcess) -> None:
    driver = Node('leg_driver', context=ros.context)
    rogue = Node('rogue', context=ros.context)
    owner = Node('owner', context=ros.context)
    try:
        reader = SourceReader(owner, JointState, '/joints', '/leg_driver', JOINT_READER_QOS)
        real = driver.create_publisher(JointState, '/joints', JOINT_READER_QOS)
        fake = rogue.create_publisher(JointState, '/joints', JOINT_READER_QOS)
        wait_until(lambda: reader.publisher_count() == 1 and fake.get_subscription_count(),
                   10.0, 'both publishers matched')
        assert not reader.unreported()
        real.publish(JointState(header=Header(frame_id='real'), position=[1.0]))
        fake.publish(JointState(header=Header(frame_id='fake'), position=[2.0]))
        got: list = []
        wait_until(lambda: got.extend(reader.take()) or reader.unreported(), 10.0,
                   'the second publisher noticed as it sends')
        wait_until(lambda: got.extend(reader.take()) or got, 10.0, 'the real message')
        assert [m.header.frame_id for m in got] == ['real']
        assert reader.foreign() == ['/rogue'] and not reader.unreported()
        rogue.destroy_publisher(fake)
        wait_until(lambda: reader.foreign() == [], 10.0, 'the second publisher gone')
    finally:
        for node in (driver, rogue, owner):
            node.destroy_node()
