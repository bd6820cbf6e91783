"""The leg driver probed as its commander would: a driver process bound to this client
(``command.commander``), the client sending its heartbeat, and the commands of issue 21's probes
that only a commander can send (a foreign sender is refused before anything else is looked
at): a trajectory stamped 0.6 s in the past, one stamped 4 s ahead, one of 100 000 points (more
than ``command.max_points``) and one of 50 000. For each: the driver's answer, the time from
the send to its receipt, and the largest interval between two encoder publications of the
driver from just before the send until after the answer (its own stamps: a stall of this
process is not the driver's), against the baseline of the same interval while nothing is
sent. ``test/test_driver_commands.py`` runs each once, ``benchmarks/faults.py`` several
times.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration as RosDuration
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell import names
from positioning_cell.config import config_path
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.messages import status_values
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.ros.qos import COMMAND_QOS, HEARTBEAT_QOS, STREAM_QOS

#: The client's node name: the driver's commander.
COMMANDER = 'driver_probe'


@dataclass(frozen=True)
class Probe:
    """One probe: what is sent and what the driver must answer (``code``, '' for accepted,
    with ``words`` in its message)."""

    name: str
    points: int
    stamp_offset_s: float | None
    code: str
    words: str


PROBES = (
    Probe('stamp 0.6 s in the past', 3, -0.6, 'old_header_timestamp', 's in the past'),
    Probe('stamp 4 s ahead', 3, 4.0, 'future_header_timestamp', 's ahead'),
    Probe('100 000 points', 100_000, None, 'too_many_points',
          '100000 points: more than max_points = 60000'),
    Probe('50 000 points', 50_000, None, '', '50000 points'),
)


@dataclass
class ProbeResult:
    """What the driver did: its answer's ``code`` ('' when accepted) and message, the time
    from the send to its receipt (s), the largest interval between its encoder stamps around
    it (s), and whether that was the expected answer."""

    probe: Probe
    code: str
    message: str
    answer_s: float
    largest_gap_s: float

    @property
    def expected(self) -> bool:
        """The answer the probe expects."""
        return self.code == self.probe.code and self.probe.words in self.message

    def line(self) -> str:
        """One line for people."""
        return (f'{self.probe.name:26s} {self.code or "accepted":24s} answer '
                f'{self.answer_s * 1e3:7.1f} ms  largest publication gap '
                f'{self.largest_gap_s * 1e3:6.1f} ms')


class CommandedDriver:
    """A leg driver process on a free domain with this client as its commander (``log_dir``:
    its log)."""

    def __init__(self, log_dir: Path) -> None:
        self._stack = contextlib.ExitStack()
        domain = self._stack.enter_context(free_domain())
        self.procs = self._stack.enter_context(Processes(cell_environment(domain), log_dir))
        self.client = self._stack.enter_context(CellClient(domain, COMMANDER))
        self.procs.start(names.DRIVER.executable, params=[config_path('cell.yaml')], overrides={
            names.NODE_DRIVER: {'referenced_at_start': True,
                                'command': {'commander': f'/{COMMANDER}'}}})
        node = self.client.node
        beat = node.create_publisher(Header, names.HEARTBEAT, HEARTBEAT_QOS)
        node.create_timer(0.05, lambda: beat.publish(Header()))
        self.trajectories = node.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY,
                                                  COMMAND_QOS)
        self.states: list[JointState] = self.client.collect(JointState, names.JOINT_STATES,
                                                            STREAM_QOS)
        self.answers: list[DiagnosticStatus] = self.client.collect(
            DiagnosticStatus, names.TRAJECTORY_STATUS, STREAM_QOS)
        status = self.client.statuses(names.STATUS_DRIVER)
        wait_until(lambda: any(status_values(s).get('commander_seen') == 'True'
                               for s in list(status)), 90.0, 'the driver to see its commander')

    def here(self) -> np.ndarray:
        """The newest encoder reading (6,)."""
        return np.array(wait_until(lambda: self.states and self.states[-1], 10.0,
                                   'an encoder reading').position)

    def quiet_gap(self, publications: int = 60) -> float:
        """The baseline: the largest interval between the driver's encoder stamps over the
        next ``publications`` publications while nothing is sent (s)."""
        count = len(self.states)
        wait_until(lambda: len(self.states) > count + publications, 30.0,
                   f'{publications} encoder readings')
        return _largest_gap(list(self.states)[count:])

    def send(self, msg: JointTrajectory) -> tuple[DiagnosticStatus, float, float]:
        """Publish ``msg``; the driver's answer, the time to its receipt (s), and the largest
        interval between the driver's encoder stamps from just before until well after."""
        seen, count = len(self.answers), len(self.states)
        sent = time.monotonic()
        self.trajectories.publish(msg)
        answer = wait_until(lambda: self.answers[seen] if len(self.answers) > seen else None,
                            30.0, 'the answer')
        took = time.monotonic() - sent
        after = len(self.states)
        wait_until(lambda: len(self.states) > after + 20, 10.0, 'encoder readings after it')
        return answer, took, _largest_gap(list(self.states)[max(count - 5, 0):])

    def probe(self, probe: Probe) -> ProbeResult:
        """Send ``probe``'s trajectory (points holding where the axes are, 0.01 s apart), then
        the stop."""
        msg = holding(self.here(), probe.points)
        if probe.stamp_offset_s is not None:
            now = self.client.node.get_clock().now()
            msg.header.stamp = (now + RosDuration(seconds=probe.stamp_offset_s)).to_msg()
        answer, took, gap = self.send(msg)
        self.trajectories.publish(JointTrajectory(joint_names=list(JOINT_NAMES)))
        values = status_values(answer)
        code = '' if values.get('accepted') == 'true' else values.get('code', '')
        return ProbeResult(probe, code, answer.message, took, gap)

    def close(self) -> dict[str, int]:
        """Stop the driver (SIGINT); its exit code."""
        try:
            return self.procs.stop()
        finally:
            self._stack.close()


def _largest_gap(states: list[JointState]) -> float:
    """The largest interval between the header stamps of ``states`` (s)."""
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in states])
    return float(np.max(np.diff(stamps)))


def holding(position: np.ndarray, points: int) -> JointTrajectory:
    """A trajectory of ``points`` points holding ``position`` (6,), 0.01 s apart."""
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    point = position.tolist()
    msg.points = [JointTrajectoryPoint(positions=point, velocities=[0.0] * 6,
                                       time_from_start=Duration(sec=k // 100,
                                                                nanosec=k % 100 * 10_000_000))
                  for k in range(points)]
    return msg


@contextlib.contextmanager
def commanded_driver(log_dir: Path) -> Iterator[CommandedDriver]:
    """A :class:`CommandedDriver`, stopped at the end."""
    driver = CommandedDriver(log_dir)
    try:
        yield driver
    finally:
        driver.close()

