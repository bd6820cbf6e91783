"""recorder_node as a separate process: a test client publishes on the cell's topics and the bag
is read back with rosbags and mcap + mcap_ros2; SIGTERM, load, pause/resume, SIGKILL +
recover_bag."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from typing import Any

import pytest
from cell_harness import Client, ProcessGroup, executable, isolated_domain, wait_until
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Vector3Stamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.duration import Duration
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from positioning_cell.bag import BagError, BagReader
from positioning_cell.nodes.qos import LATCHED_QOS, STREAM_QOS

pytestmark = pytest.mark.nodes

# Streams of the cell used by the tests: topic → message type
STREAMS = {
    '/legs/joint_states': JointState,
    '/positioner/pose': PoseStamped,
    '/metrology/pose': PoseWithCovarianceStamped,
    '/accuracy/position_error': Vector3Stamped,
    '/sim/platform/true_pose': PoseStamped,
}
# Keep-all publishers for the load test: only the recorder can lose a message, not the sender.
KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


def _message(msg_type: Any, i: int) -> Any:
    """Message number ``i``: the index is in the header stamp (sec) for every type."""
    msg = msg_type()
    msg.header.stamp.sec = i
    msg.header.frame_id = 'base'
    if msg_type is JointState:
        msg.name = ['leg1_length']
        msg.position = [0.2 + 1e-6 * i]
    return msg


def _start_recorder(group: ProcessGroup, tmp_path: Path, **params: Any) -> Path:
    """Start recorder_node writing to tmp_path/bag (own section in a second params file, which
    wins over config/cell.yaml's); returns the bag path."""
    bag = tmp_path / 'bag'
    lines = [f'    output: {bag}', '    flush_period_s: 0.2', '    discovery_period_s: 0.2']
    lines += [f'    {k}: {v}' for k, v in params.items()]
    override = tmp_path / 'recorder.yaml'
    override.write_text('recorder:\n  ros__parameters:\n' + '\n'.join(lines) + '\n')
    group.start('recorder_node', '--params-file', str(override), label='recorder')
    return bag


def _subscribed(publishers: dict[str, Any]) -> bool:
    return all(p.get_subscription_count() > 0 for p in publishers.values())


def _recorder_status(diagnostics: list[DiagnosticArray]) -> dict[str, str]:
    """Values of the recorder's latest diagnostic status ({} before the first)."""
    for array in reversed(diagnostics):
        for status in array.status:
            if status.name == 'recorder':
                return {kv.key: kv.value for kv in status.values}
    return {}


def _warm_up(client: Client, pubs: dict[str, Any], types: dict[str, Any]) -> None:
    """Publish markers (stamp -1) until the recorder has recorded one on every topic: a
    publisher that sees the subscription may still be unknown to the subscriber (DDS discovery
    is not symmetric), and a volatile reader drops what came before it matched."""
    diagnostics = client.collect(DiagnosticArray, '/diagnostics')

    def ready() -> bool:
        counts = _recorder_status(diagnostics)
        missing = [t for t in pubs if int(counts.get(t, 0)) == 0]
        for topic in missing:
            pubs[topic].publish(_message(types[topic], -1))
        return not missing
    wait_until(ready, 30, 'the recorder to record a marker on every topic', poll=0.3)


def _stamps(bag: Path) -> dict[str, list[int]]:
    """Header stamp seconds (= message index) per topic, decoded by rosbags; markers (-1)
    left out."""
    out: dict[str, list[int]] = {}
    with BagReader(bag) as reader:
        for item in reader.messages():
            if item.message.header.stamp.sec >= 0:
                out.setdefault(item.topic, []).append(item.message.header.stamp.sec)
    return out


def _mcap_counts(bag: Path) -> dict[str, int]:
    """Messages per topic decoded by mcap + mcap_ros2 (independent of rosbags), markers left
    out."""
    counts: dict[str, int] = {}
    for path in sorted(bag.glob('*.mcap')):
        with path.open('rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, _, decoded in reader.iter_decoded_messages():
                if decoded.header.stamp.sec >= 0:  # markers left out
                    counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_records_cell_topics_and_closes_on_sigterm(tmp_path: Path) -> None:
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain) as client:
        pubs = {t: client.node.create_publisher(m, t, STREAM_QOS) for t, m in STREAMS.items()}
        target = client.node.create_publisher(PoseStamped, '/positioner/target', LATCHED_QOS)
        target.publish(_message(PoseStamped, 7))  # latched before the recorder exists
        diagnostics = client.collect(DiagnosticArray, '/diagnostics')
        bag = _start_recorder(group, tmp_path)
        wait_until(lambda: _subscribed({**pubs, 't': target}), 15, 'recorder subscriptions')
        _warm_up(client, pubs, STREAMS)
        base = int(_recorder_status(diagnostics)['messages'])

        for i in range(200):
            for topic, pub in pubs.items():
                pub.publish(_message(STREAMS[topic], i))
        wait_until(lambda: int(_recorder_status(diagnostics)['messages']) >= base + 1000, 15,
                   'the recorder to write 1000 more messages')
        paused = client.call(Trigger, '/recorder/pause', Trigger.Request())
        assert paused.success and paused.message.startswith('paused')
        for i in range(1000, 1050):
            pubs['/legs/joint_states'].publish(_message(JointState, i))
        wait_until(lambda: int(_recorder_status(diagnostics).get('dropped_while_paused', 0))
                   >= 50, 15, 'the paused recorder to drop 50 messages')
        resumed = client.call(Trigger, '/recorder/resume', Trigger.Request())
        assert resumed.success and resumed.message.startswith('recording')
        for i in range(2000, 2100):
            pubs['/legs/joint_states'].publish(_message(JointState, i))
        for pub in pubs.values():
            assert pub.wait_for_all_acked(Duration(seconds=10))
        # SIGTERM at once: what the recorder received but did not process yet is recorded too
        assert group.stop('recorder', sig=signal.SIGTERM) == {'recorder': 0}

    stamps = _stamps(bag)
    expected = list(range(200))
    assert stamps['/legs/joint_states'] == expected + list(range(2000, 2100))
    for topic in STREAMS:
        if topic != '/legs/joint_states':
            assert stamps[topic] == expected, topic
    assert stamps['/positioner/target'] == [7]  # transient-local: caught though published first
    counts = _mcap_counts(bag)
    assert {t: counts[t] for t in stamps} == {t: len(v) for t, v in stamps.items()}
    with BagReader(bag) as reader:
        latched = reader.topics['/positioner/target'].qos
        assert latched and latched[0].durability.name == 'TRANSIENT_LOCAL'
        assert reader.topics['/legs/joint_states'].qos[0].reliability.name == 'RELIABLE'


def test_lossless_under_load(tmp_path: Path) -> None:
    per_topic = 2100  # 10 500 messages over five cell topics, published as fast as possible
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain) as client:
        pubs = {t: client.node.create_publisher(m, t, KEEP_ALL) for t, m in STREAMS.items()}
        messages = {t: [_message(STREAMS[t], i) for i in range(per_topic)] for t in STREAMS}
        bag = _start_recorder(group, tmp_path, compression='zstd')
        wait_until(lambda: _subscribed(pubs), 15, 'recorder subscriptions')
        _warm_up(client, pubs, STREAMS)
        for i in range(per_topic):
            for topic, pub in pubs.items():
                pub.publish(messages[topic][i])
        for pub in pubs.values():
            assert pub.wait_for_all_acked(Duration(seconds=30))
        assert group.stop('recorder', sig=signal.SIGINT) == {'recorder': 0}

    stamps = _stamps(bag)
    for topic in STREAMS:
        assert stamps[topic] == list(range(per_topic)), topic
    assert sum(len(stamps[t]) for t in STREAMS) >= 10_000
    counts = _mcap_counts(bag)
    assert all(counts[t] == per_topic for t in STREAMS)


def test_sigkill_then_recover_bag(tmp_path: Path) -> None:
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain) as client:
        pub = client.node.create_publisher(JointState, '/legs/joint_states', STREAM_QOS)
        diagnostics = client.collect(DiagnosticArray, '/diagnostics')
        bag = _start_recorder(group, tmp_path)
        wait_until(lambda: pub.get_subscription_count() > 0, 15, 'recorder subscription')
        _warm_up(client, {'/legs/joint_states': pub}, STREAMS)
        for i in range(500):
            pub.publish(_message(JointState, i))
        wait_until(lambda: int(_recorder_status(diagnostics).get('/legs/joint_states', 0))
                   >= 500, 15, 'the recorder to write 500 messages')
        # pause flushes: these 500 are on disk; the kill must not lose them
        assert client.call(Trigger, '/recorder/pause', Trigger.Request()).success
        group.stop('recorder', sig=signal.SIGKILL)

    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(BagError, match='recover_bag'):
        BagReader(bag)
    done = subprocess.run([executable('recover_bag'), str(bag)], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert 'recovered' in done.stdout
    assert _stamps(bag)['/legs/joint_states'] == list(range(500))
    assert _mcap_counts(bag)['/legs/joint_states'] == 500
    again = subprocess.run([executable('recover_bag'), str(bag)], capture_output=True, text=True,
                           timeout=60, check=False)
    assert again.returncode == 0 and 'nothing changed' in again.stdout
    bad = subprocess.run([executable('recover_bag'), str(tmp_path / 'no_such_bag')],
                         capture_output=True, text=True, timeout=60, check=False)
    assert bad.returncode == 1 and 'not a bag directory' in bad.stderr


def test_refuses_to_overwrite_a_bag(tmp_path: Path) -> None:
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'metadata.yaml').write_text('precious')
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group:
        override = tmp_path / 'recorder.yaml'
        override.write_text(f'recorder:\n  ros__parameters:\n    output: {tmp_path / "bag"}\n')
        proc = group.start('recorder_node', '--params-file', str(override), label='recorder')
        assert proc.wait(timeout=30) == 2
        assert 'exists already' in group.log('recorder')
    assert (tmp_path / 'bag' / 'metadata.yaml').read_text() == 'precious'

