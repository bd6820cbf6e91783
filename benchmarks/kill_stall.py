"""What a subscriber killed inside its receive path does to its publisher, with the shipped Fast
DDS profile (config/fastdds_loopback.xml: UDPv4 on 127.0.0.1 alone) and, as the baseline, the
same profile with the shared-memory transport it had before added back.

A writer process publishes two reliable 500 Hz JointState streams (the cell's STREAM_QOS) and
times every publish(); a reader process subscribes to both (LATEST_QOS). Once the reader has
received, gdb attaches to it with a breakpoint in each Fast DDS receive thread of the
transport under test on the lock it takes (``dds.shm.<port>``: pthread_mutex_timedlock called
from Boost's interprocess_mutex, its port's lock in the segment the writer shares;
``dds.udp.<port>``: pthread_mutex_lock, a lock of the reader's own), lets the reader run until
one stops there, deletes the other breakpoints (or another thread's could cut the next step
short), finishes that call (the thread now holds the lock) and SIGKILLs the reader. Reported
per trial: the longest publish() and the time spent in publish() calls over 50 ms, from the
breakpoint to 5 s after the kill.

This is how the cell met it: the tracker SIGKILLed by the fault matrix, the driver's joint
states silent for 1 s, the positioner aborting as if the driver had died (docs/howto/run.md).
Fast DDS builds Boost's interprocess mutex to give up after 1000 ms
(BOOST_INTERPROCESS_TIMEOUT_WHEN_LOCKING_DURATION_MS): each write to the dead reader's port
waits that long until the port is found broken.

Run: .venv/bin/python benchmarks/kill_stall.py [--trials 3]   (needs gdb)
Target: with the shipped profile no publish() over 0.1 s after such a kill. Prints what it
measured; exits 1 if the target is not met, non-zero with the reason if it could not measure
(the reader did not start, gdb did not stop it); without gdb it says so and skips.
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

from positioning_cell.config import config_path
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.processes import cell_environment

SLOW_S = 0.05  # a publish() longer than this is reported by the writer
AFTER_S = 5.0  # s watched after the kill
TARGET_S = 0.1

WRITER = f"""
import sys, threading, time
import rclpy
from sensor_msgs.msg import JointState
from positioning_cell.ros.qos import STREAM_QOS
rclpy.init()
node = rclpy.create_node('kill_stall_writer')
def run(topic):
    pub = node.create_publisher(JointState, topic, STREAM_QOS)
    msg = JointState(name=['a', 'b', 'c', 'd', 'e', 'f'], position=[0.1] * 6)
    due = time.monotonic()
    while True:
        t0 = time.monotonic()
        pub.publish(msg)
        took = time.monotonic() - t0
        if took > {SLOW_S}:
            print(f'slow {{t0:.6f}} {{took:.6f}}', flush=True)
        due += 0.002
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        else:
            due = time.monotonic()
for topic in ('/kill_stall/a', '/kill_stall/b'):
    threading.Thread(target=run, args=(topic,), daemon=True).start()
print('writing', flush=True)
threading.Event().wait()
"""

READER = """
import rclpy
from sensor_msgs.msg import JointState
from positioning_cell.ros.qos import LATEST_QOS
rclpy.init()
node = rclpy.create_node('kill_stall_reader')
heard = []
def heard_one(_):
    if not heard:
        print('heard', flush=True)
    heard.append(1)
for topic in ('/kill_stall/a', '/kill_stall/b'):
    node.create_subscription(JointState, topic, heard_one, LATEST_QOS)
rclpy.spin(node)
"""

#: gdb's commands: a breakpoint on the lock every Fast DDS receive thread takes (a shared-memory
#: listener: its port's interprocess mutex, the timed lock Boost's interprocess_mutex calls; a
#: UDP one: its own mutexes), run to the first such call, finish it (the lock is held), note
#: the time, kill the process.
GDB = """
set pagination off
python
import os, re, time, gdb
LOCKS = {'shm': 'pthread_mutex_timedlock', 'udp': 'pthread_mutex_lock'}
kinds = {}
for t in gdb.selected_inferior().threads():
    kind = re.fullmatch(r'dds\\.(KIND)\\.\\d+', t.name or '')
    if kind:
        gdb.Breakpoint(LOCKS[kind.group(1)]).thread = t.num
        kinds[t.num] = kind.group(1)
for _ in range(1000):
    gdb.execute('continue')
    caller = gdb.selected_frame().older()
    if kinds.get(gdb.selected_thread().num) == 'udp' or (
            caller is not None and 'interprocess_mutex' in str(caller.name())):
        break
for b in gdb.breakpoints():
    b.delete()
gdb.execute('finish')
print(f'held {time.monotonic():.6f} in', gdb.selected_thread().name, flush=True)
os.kill(gdb.selected_inferior().pid, 9)
end
"""


def with_shared_memory(shipped: Path, out: Path) -> Path:
    """The shipped profile with a shared-memory transport added to the participant's (the
    profile as it was before it went to UDP alone)."""
    text = shipped.read_text()
    descriptor = ('<transport_descriptor><transport_id>shm</transport_id><type>SHM</type>'
                  '</transport_descriptor>\n    </transport_descriptors>')
    used = '<transport_id>udp_loopback</transport_id>\n          <transport_id>shm</transport_id>'
    for old, new in (('</transport_descriptors>', descriptor),
                     ('<transport_id>udp_loopback</transport_id>\n        </userTransports>',
                      used + '\n        </userTransports>')):
        if text.count(old) != 1:
            raise SystemExit(f'{shipped}: cannot add the shared-memory transport ({old!r})')
        text = text.replace(old, new)
    out.write_text(text)
    return out


def line_from(proc: subprocess.Popen[str], word: str, timeout: float) -> str:
    """The first line of ``proc``'s stdout that starts with ``word`` (within ``timeout`` s)."""
    end = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if line.startswith(word):
            return line
        if not line and proc.poll() is not None:
            break
    raise SystemExit(f'no "{word}" line from {proc.args!r} in {timeout} s: cannot measure')


def trial(env: dict[str, str], kind: str) -> tuple[float, float, str]:
    """One kill in a receive thread of the transport ``kind`` ('shm' or 'udp'): (longest
    publish() s, time in slow publish() calls s, the thread held)."""
    python = sys.executable
    writer = subprocess.Popen([python, '-c', WRITER], env=env, stdout=subprocess.PIPE,
                              text=True)
    reader = subprocess.Popen([python, '-c', READER], env=env, stdout=subprocess.PIPE,
                              text=True)
    try:
        line_from(writer, 'writing', 60.0)
        line_from(reader, 'heard', 60.0)
        commands = GDB_FILE.with_suffix(f'.{kind}.gdb')
        commands.write_text(GDB.replace('KIND', kind))
        gdb = subprocess.run(['gdb', '-p', str(reader.pid), '-batch', '-nx', '-ex',
                              f'source {commands}'], capture_output=True, text=True,
                             timeout=60.0, check=False)
        commands.unlink()
        held = [ln for ln in gdb.stdout.splitlines() if ln.startswith('held ')]
        if not held:
            raise SystemExit(f'gdb did not stop the reader in a receive thread:\n{gdb.stdout}'
                             f'\n{gdb.stderr}')
        held_at, thread = float(held[0].split()[1]), held[0].split()[-1]
        reader.wait(10.0)
        time.sleep(AFTER_S)
    finally:
        for proc in (reader, writer):
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
            proc.wait()
    assert writer.stdout is not None
    slow = [(float(t0), float(took)) for _, t0, took in
            (ln.split() for ln in writer.stdout.read().splitlines() if ln.startswith('slow '))]
    after = [took for t0, took in slow if t0 + took >= held_at]
    return max(after, default=0.0), sum(after), thread


GDB_FILE = Path(tempfile.gettempdir()) / f'kill_stall_{os.getpid()}'


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--trials', type=int, default=3)
    args = parser.parse_args(argv)
    if shutil.which('gdb') is None:
        print('skipped: gdb not found (it holds the reader inside its lock)')
        return 0
    shipped = config_path('fastdds_loopback.xml')
    worst: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        profiles = {'shipped (UDP alone)': (shipped, 'udp'),
                    'baseline (with shared memory)': (with_shared_memory(
                        shipped, Path(tmp) / 'with_shm.xml'), 'shm')}
        for label, (profile, kind) in profiles.items():
            rows = []
            for _ in range(args.trials):
                with free_domain() as domain:
                    env = cell_environment(domain, dict(
                        os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='SYSTEM_DEFAULT'))
                    rows.append(trial(env, kind))
            worst[label] = max(r[0] for r in rows)
            for longest, total, thread in rows:
                print(f'{label:30s} lock held in {thread:14s} longest publish() '
                      f'{longest * 1e3:7.1f} ms, {total:5.2f} s in publish() calls over '
                      f'{SLOW_S * 1e3:.0f} ms')
    met = worst['shipped (UDP alone)'] <= TARGET_S
    print(f'target: no publish() over {TARGET_S * 1e3:.0f} ms after the kill with the shipped '
          f'profile: {"met" if met else "NOT met"} ({worst["shipped (UDP alone)"] * 1e3:.1f} '
          f'ms; baseline {worst["baseline (with shared memory)"] * 1e3:.1f} ms)')
    return 0 if met else 1


if __name__ == '__main__':
    sys.exit(main())
