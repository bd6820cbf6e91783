"""Recorder benchmarks (figures vary ±20-50 % on the shared 2-core VMs; see platform.md).

1. Raw writer throughput without ROS: pre-serialized cell messages → BagWriter (none, zstd).
2. A bag of 1 000 000 messages across the cell's topics, kept for the analysis benchmark
   (path printed; ``--large-bag-messages`` changes the size).
3. Recording through DDS across processes: ``recorder_node`` in its own process, a publisher
   process sends N pre-serialized messages round-robin over the cell's topics as fast as it
   can (reliable, keep-all, so only the recorder can lose any) after one acknowledged warm-up
   message per topic; then SIGINT, and the bag is read back to count. Reported: the publish
   rate achieved, the recorder's receive rate (first to last log time of the burst) and lost
   messages (must be 0).

Run: ``.venv/bin/python benchmarks/recorder.py`` (add ``--quick`` for a short run).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from positioning_cell.bag import CELL_TOPICS, BagReader, BagWriter
from positioning_cell.bag.writer import jazzy_typestore

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent

# (topic, type) of the cell's streams (design/interfaces.md) used in every benchmark.
STREAMS = [
    ('/legs/joint_states', 'sensor_msgs/msg/JointState'),
    ('/sim/legs/true_joint_states', 'sensor_msgs/msg/JointState'),
    ('/positioner/pose', 'geometry_msgs/msg/PoseStamped'),
    ('/metrology/pose', 'geometry_msgs/msg/PoseWithCovarianceStamped'),
    ('/sim/platform/true_pose', 'geometry_msgs/msg/PoseStamped'),
    ('/accuracy/position_error', 'geometry_msgs/msg/Vector3Stamped'),
    ('/accuracy/orientation_error', 'geometry_msgs/msg/Vector3Stamped'),
]
JOINTS = ['leg1_length', 'leg2_length', 'leg3_length', 'leg1_theta', 'leg2_theta', 'leg3_theta']


def sample_messages(seed: int = 0) -> dict[str, bytes]:
    """One realistic CDR message per stream topic, serialized by rosbags (Jazzy definitions)."""
    ts = jazzy_typestore()
    rng = np.random.default_rng(seed)
    T, H = ts.types['builtin_interfaces/msg/Time'], ts.types['std_msgs/msg/Header']
    P, Q = ts.types['geometry_msgs/msg/Point'], ts.types['geometry_msgs/msg/Quaternion']
    pose = ts.types['geometry_msgs/msg/Pose'](P(0.001, -0.002, 0.197), Q(0.0, 0.0, 0.0, 1.0))
    header = H(T(1_700_000_000, 123), 'base')
    vec = ts.types['geometry_msgs/msg/Vector3'](1e-4, -2e-4, 3e-4)
    js = ts.types['sensor_msgs/msg/JointState'](header, JOINTS, rng.normal(size=6),
                                                rng.normal(size=6), rng.normal(size=6))
    cov = ts.types['geometry_msgs/msg/PoseWithCovariance'](pose, rng.normal(size=36))
    values = {
        'sensor_msgs/msg/JointState': js,
        'geometry_msgs/msg/PoseStamped': ts.types['geometry_msgs/msg/PoseStamped'](header, pose),
        'geometry_msgs/msg/PoseWithCovarianceStamped':
            ts.types['geometry_msgs/msg/PoseWithCovarianceStamped'](header, cov),
        'geometry_msgs/msg/Vector3Stamped': ts.types['geometry_msgs/msg/Vector3Stamped'](
            header, vec),
    }
    return {topic: bytes(ts.serialize_cdr(values[msgtype], msgtype))
            for topic, msgtype in STREAMS}


def write_bag(path: Path, count: int, compression: str, period_ns: int = 1000) -> float:
    """Write ``count`` messages round-robin over STREAMS into a new bag; seconds taken."""
    data = sample_messages()
    items = [(topic, msgtype, data[topic]) for topic, msgtype in STREAMS]
    t0_ns = time.time_ns()
    start = time.perf_counter()
    with BagWriter(path, compression=compression) as writer:
        for i in range(count):
            topic, msgtype, raw = items[i % len(items)]
            writer.write(topic, msgtype, raw, t0_ns + i * period_ns)
            if i % 20_000 == 0:
                writer.flush()
    return time.perf_counter() - start


def bag_size(path: Path) -> int:
    """Bytes of all files of a bag."""
    return sum(f.stat().st_size for f in path.iterdir())


def bench_writer(count: int, workdir: Path) -> None:
    for compression in ('none', 'zstd'):
        path = workdir / f'writer_{compression}'
        seconds = write_bag(path, count, compression)
        print(f'raw BagWriter, no ROS, {compression:4s}: {count} msgs in {seconds:.2f} s = '
              f'{count / seconds:,.0f} msgs/s, {bag_size(path) / count:.0f} B/msg on disk')
        shutil.rmtree(path)


def bench_large_bag(count: int) -> Path:
    path = Path(tempfile.gettempdir()) / 'positioning_cell_bench' / f'recorder_{count}'
    shutil.rmtree(path, ignore_errors=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    seconds = write_bag(path, count, 'zstd', period_ns=100_000)
    with BagReader(path) as reader:
        assert reader.message_count == count, reader.message_count
    print(f'large bag: {count} messages, {len(STREAMS)} topics, zstd, '
          f'{bag_size(path) / 2**20:.1f} MiB, written in {seconds:.1f} s '
          f'({count / seconds:,.0f} msgs/s): {path}')
    return path


PUBLISHER = r'''
import sys, time
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, HistoryPolicy, ReliabilityPolicy
from positioning_cell.bag import message_class
sys.path.insert(0, sys.argv[3])
from recorder import STREAMS, sample_messages
count = int(sys.argv[1]); rate = float(sys.argv[2])
rclpy.init()
node = Node('bench_publisher')
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
data = sample_messages()
pubs = [(node.create_publisher(message_class(t), topic, qos), data[topic]) for topic, t in STREAMS]
deadline = time.monotonic() + 60
while min(p.get_subscription_count() for p, _ in pubs) < 1:
    if time.monotonic() > deadline:
        sys.exit('recorder did not subscribe')
    time.sleep(0.05)
# one acknowledged message per topic first: both ends matched before the timed burst
for pub, raw in pubs:
    pub.publish(raw)
    if not pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30)):
        sys.exit('warm-up message not acknowledged')
start = time.perf_counter()
n = len(pubs)
refused = 0
for i in range(count):
    if rate > 0:
        while time.perf_counter() - start < i / rate:
            pass
    pub, raw = pubs[i % n]
    while True:  # a full keep-all writer history refuses (back-pressure): retry shortly
        try:
            pub.publish(raw)
            break
        except rclpy._rclpy_pybind11.RCLError:
            refused += 1
            time.sleep(0.001)
elapsed = time.perf_counter() - start
for pub, _ in pubs:
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30))
print(f'{count / elapsed:.0f} {refused}')
node.destroy_node()
rclpy.shutdown()
'''


def bench_recorder(count: int, rate: float, workdir: Path, domain: int) -> None:
    """One recording run through DDS; prints rates and losses."""
    bag = workdir / f'dds_{count}_{int(rate)}'
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env.setdefault('ROS_LOG_DIR', str(workdir / 'ros_log'))
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
    # A node's own section beats `-p` overrides (which apply to /**): a second params file.
    override = workdir / 'recorder_override.yaml'
    override.write_text(f'recorder:\n  ros__parameters:\n    output: {bag}\n')
    recorder = subprocess.Popen(
        [str(BIN / 'recorder_node'), '--ros-args', '--params-file', str(REPO / 'config/cell.yaml'),
         '--params-file', str(override)], env=env, stdout=subprocess.DEVNULL,
        stderr=(workdir / 'recorder.log').open('wb'), start_new_session=True)
    try:
        out = subprocess.run([sys.executable, '-c', PUBLISHER, str(count), str(rate),
                              str(Path(__file__).parent)], env=env, capture_output=True,
                             text=True, timeout=600, check=False)
        if out.returncode != 0:
            raise RuntimeError(f'benchmark publisher failed: {out.stderr[-2000:]}')
        rate_text, refused = out.stdout.strip().splitlines()[-1].split()
        published_rate = float(rate_text)
    finally:
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=60)
    with BagReader(bag) as reader:  # the recorder also records its own /diagnostics
        times = np.fromiter((m.log_time_ns for m in reader.raw_messages(
            [t for t, _ in STREAMS if t in reader.topics])), dtype=np.int64)
    got = len(times) - len(STREAMS)  # the warm-up messages come first
    span = (times[-1] - times[len(STREAMS)]) * 1e-9 if got > 1 else 0.0
    want = 'full rate' if rate <= 0 else f'paced at {rate:,.0f}/s'
    print(f'recorder through DDS ({want}): {count} published at {published_rate:,.0f} msgs/s '
          f'({refused} publishes refused by a full writer history and retried), '
          f'{got} recorded at {got / span if span else float("nan"):,.0f} msgs/s, '
          f'lost {count - got}')
    shutil.rmtree(bag)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='small counts')
    parser.add_argument('--large-bag-messages', type=int, default=1_000_000)
    parser.add_argument('--dds-messages', type=int, default=100_000)
    args = parser.parse_args()
    quick = args.quick
    sys.path.insert(0, str(REPO / 'test'))
    from cell_harness import isolated_domain  # a ROS_DOMAIN_ID no test process holds

    with tempfile.TemporaryDirectory(prefix='recorder_bench_') as tmp, \
            isolated_domain() as domain:
        workdir = Path(tmp)
        bench_writer(50_000 if quick else 200_000, workdir)
        bench_large_bag(50_000 if quick else args.large_bag_messages)
        n = 10_000 if quick else args.dds_messages
        bench_recorder(n, 0.0, workdir, domain)
        for rate in (() if quick else (10_000.0, 20_000.0)):
            bench_recorder(n, rate, workdir, domain)
    print(f'(topics of the cell: {len(CELL_TOPICS)}; streams used: {len(STREAMS)})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
