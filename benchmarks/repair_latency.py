"""How late a reliable message comes when the kernel dropped its datagram, with the shipped Fast
DDS profile (config/fastdds_loopback.xml: UDPv4 on 127.0.0.1 alone, its writers' heartbeat
period) and, as the baseline, the same profile with Fast DDS's default heartbeat period (3 s).

Over UDP a datagram is dropped when its reader's receive buffer is full (a loaded machine: the
suite's tiers counted thousands, UdpRcvbufErrors in /proc/net/snmp). A reliable reader learns
of the loss from its writer's next heartbeat and asks for the sample again, so the sample comes
up to one heartbeat period late, while the other topics' messages keep arriving: the order in
which a reader (the accuracy monitor, the recorder) sees a target, a move end and the tracker's
readings can then differ from one reader to the next by that much (docs/howto/run.md).

A writer process publishes bursts of reliable messages (the cell's DIAGNOSTICS_QOS, the
/diagnostics and command profile: depth 1000) at 2 Hz, each carrying its sequence number and
its publish time (time.monotonic, one clock for both processes); a reader process, with a
receive buffer made small so that a burst overflows it, notes when each arrives. Reported per
profile: the messages written and received (a keep-last writer whose history fills before its
readers acknowledge overwrites what they never got), how many came over 50 ms after their
publish (repaired), and the latency of the latest.

Run: .venv/bin/python benchmarks/repair_latency.py [--bursts 10]
Target: with the shipped profile every message received, within 0.5 s of its publish (the accuracy
monitor's settle window and dwell: a reading, target or move end later than that can change
which window settles a visit). Prints what it measured; exits 1 if the target is not met,
non-zero with the reason if it could not measure (no drop, a process did not start).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from positioning_cell.config import config_path
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.processes import cell_environment

TARGET_S = 0.5
LATE_S = 0.05  # a message later than this was repaired (none came that late undropped here)
BURST = 300  # messages a burst: more than the small receive buffer holds
#: The reader's receive buffer, bytes (the kernel doubles it): a burst overflows it.
SMALL_BUFFER = 16384

WRITER = f"""
import sys, time
import rclpy
from std_msgs.msg import Float64MultiArray
from positioning_cell.ros.qos import DIAGNOSTICS_QOS
rclpy.init()
node = rclpy.create_node('repair_latency_writer')
pub = node.create_publisher(Float64MultiArray, '/repair_latency', DIAGNOSTICS_QOS)
while pub.get_subscription_count() == 0:
    time.sleep(0.01)
time.sleep(1.0)  # the reader's end of the match too
print('writing', flush=True)
seq = 0
for _ in range(int(sys.argv[1])):
    for _ in range({BURST}):
        pub.publish(Float64MultiArray(data=[float(seq), time.monotonic()]))
        seq += 1
    time.sleep(0.5)
print('wrote', seq, flush=True)
time.sleep(5.0)  # heartbeats for the last repairs
"""

READER = """
import sys, time
import rclpy
from std_msgs.msg import Float64MultiArray
from positioning_cell.ros.qos import DIAGNOSTICS_QOS
rclpy.init()
node = rclpy.create_node('repair_latency_reader')
out = open(sys.argv[1], 'w', buffering=1)
node.create_subscription(
    Float64MultiArray, '/repair_latency',
    lambda m: out.write(f'{int(m.data[0])} {time.monotonic() - m.data[1]:.6f}\\n'),
    DIAGNOSTICS_QOS)
rclpy.spin(node)
"""


def variant(shipped: Path, out: Path, *, default_heartbeat: bool, small_buffer: bool) -> Path:
    """The shipped profile, without its writers' heartbeat period (Fast DDS's default then) and
    with a small receive buffer on its UDP transport, as asked."""
    text = shipped.read_text()
    if default_heartbeat:
        start, end = text.find('<data_writer'), text.find('</data_writer>')
        if start < 0 or end < 0:
            raise SystemExit(f'{shipped}: no data_writer profile to take out')
        text = text[:start] + text[end + len('</data_writer>'):]
    if small_buffer:
        old = '<type>UDPv4</type>'
        if text.count(old) != 1:
            raise SystemExit(f'{shipped}: expected one UDPv4 transport')
        text = text.replace(old, f'{old}<receiveBufferSize>{SMALL_BUFFER}</receiveBufferSize>'
                                 f'<maxMessageSize>{SMALL_BUFFER}</maxMessageSize>')
    out.write_text(text)
    return out


def trial(writer_env: dict[str, str], reader_env: dict[str, str], bursts: int,
          log: Path) -> tuple[int, list[float]]:
    """One run: (messages written, the latency s of each received)."""
    reader = subprocess.Popen([sys.executable, '-c', READER, str(log)], env=reader_env)
    writer = subprocess.Popen([sys.executable, '-c', WRITER, str(bursts)], env=writer_env,
                              stdout=subprocess.PIPE, text=True)
    try:
        out, _ = writer.communicate(timeout=120.0 + bursts)
    finally:
        for proc in (writer, reader):
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
            proc.wait()
    wrote = [ln for ln in out.splitlines() if ln.startswith('wrote ')]
    if not wrote:
        raise SystemExit(f'the writer did not finish:\n{out}')
    latency = [float(ln.split()[1]) for ln in log.read_text().splitlines() if ln.strip()]
    return int(wrote[0].split()[1]), latency


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--bursts', type=int, default=10)
    parser.add_argument('--trials', type=int, default=2)
    args = parser.parse_args(argv)
    shipped = config_path('fastdds_loopback.xml')
    latest: dict[str, float] = {}
    missing: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        small = variant(shipped, folder / 'reader.xml', default_heartbeat=False,
                        small_buffer=True)
        profiles = {'shipped': shipped,
                    'baseline (3 s heartbeat)': variant(shipped, folder / 'baseline.xml',
                                                        default_heartbeat=True,
                                                        small_buffer=False)}
        small_default = variant(shipped, folder / 'reader_default.xml', default_heartbeat=True,
                                small_buffer=True)
        for t in range(args.trials):  # alternated
            for label, profile in profiles.items():
                with free_domain() as domain:
                    base = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='SYSTEM_DEFAULT')
                    writer_env = cell_environment(domain, dict(
                        base, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile)))
                    reader_env = cell_environment(domain, dict(
                        base, FASTRTPS_DEFAULT_PROFILES_FILE=str(
                            small if label == 'shipped' else small_default)))
                    wrote, latency = trial(writer_env, reader_env, args.bursts,
                                           folder / f'{t}_{len(latest)}.log')
                late = [x for x in latency if x > LATE_S]
                if not late:
                    raise SystemExit(f'{label}: no message came over {LATE_S * 1e3:.0f} ms '
                                     'late: nothing was dropped, nothing to measure')
                latest[label] = max(latest.get(label, 0.0), *latency)
                missing[label] = missing.get(label, 0) + wrote - len(latency)
                print(f'{label:26s} {wrote} written, {len(latency)} received, '
                      f'{len(late)} over {LATE_S * 1e3:.0f} ms late, latest '
                      f'{max(latency):.3f} s')
    worst = latest['shipped']
    met = worst <= TARGET_S and missing['shipped'] == 0
    print(f'target: every message, within {TARGET_S:g} s, with the shipped profile: '
          f'{"met" if met else "NOT met"} ({worst:.3f} s, {missing["shipped"]} missing; '
          f'baseline {latest["baseline (3 s heartbeat)"]:.3f} s, '
          f'{missing["baseline (3 s heartbeat)"]} missing)')
    return 0 if met else 1


if __name__ == '__main__':
    sys.exit(main())
