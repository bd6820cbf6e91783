"""The drives' commands as they arrive: trajectories taken in the order received, each decoded
and checked on a thread of its own while the drives keep moving and publishing, then applied
by the drives' own loop; a command from a foreign sender refused at once, a stop applied at
once (what waits for its checks is superseded).

Times on the drives' clock (s since ``epoch_ns`` of the ROS clock, :class:`CommandQueue`).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from positioning_cell.sim.drives import LegDriver, Outcome, Prepared, foreign_sender
from positioning_cell.sim.guard import Refusal
from positioning_cell.sim.trajectory_wire import (
    Peek,
    TrajectoryWireError,
    decode_joint_trajectory,
    peek,
)

FloatArray = NDArray[np.float64]


class CommandQueue:
    """Commands for ``driver`` (module docstring): :meth:`receive` each one taken (serialized
    JointTrajectory, sender node, receipt time), :meth:`pump` on every step of the drives.
    Both return the outcomes to answer, in the order the commands came."""

    def __init__(self, driver: LegDriver, epoch_ns: int) -> None:
        self.driver = driver
        self.epoch_ns = epoch_ns
        self._waiting: deque[tuple[bytes, str, float, Peek]] = deque()
        self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='trajectory_checks')
        self._work: Future[Prepared | Outcome] | None = None
        self._cancelled = False

    def receive(self, data: bytes, sender: str, now: float) -> tuple[list[Outcome], str | None]:
        """A command taken at ``now``: the outcomes it settles at once (a foreign sender, bytes
        that are not a trajectory, what a stop supersedes) and the event of a stop it applied
        (the empty trajectory), or None."""
        command = self.driver.settings.command
        if sender != command.commander:
            self.driver.note_foreign(sender)
            return [self.driver.refuse(Refusal.FOREIGN_SENDER,
                                       foreign_sender(sender, command))], None
        try:
            header = peek(data)
        except TrajectoryWireError as err:
            return [self.driver.refuse(Refusal.INVALID_GOAL,
                                       f'not a trajectory the drives take: {err}')], None
        if header.points:
            self._waiting.append((data, sender, now, header))
            return [], None
        superseded = len(self._waiting)
        self._waiting.clear()
        self._cancelled = self._work is not None
        event = self.driver.stop(now)
        return [self.driver.refuse(Refusal.SUPERSEDED, 'superseded by a stop before it was '
                                   'checked') for _ in range(superseded)], event

    def pump(self, now: float) -> list[Outcome]:
        """Apply the trajectory whose checks are done (on this, the drives' thread), then
        start the checks of the next; the outcome of the one applied."""
        done: list[Outcome] = []
        if self._work is not None:
            if not self._work.done():
                return done
            prepared = self._work.result()
            self._work = None
            if self._cancelled:
                self._cancelled = False
                done.append(self.driver.refuse(Refusal.SUPERSEDED, 'superseded by a stop '
                                               'before it started', prepared.key))
            else:
                done.append(self.driver.apply(prepared, now))
        if self._waiting:
            data, sender, received, header = self._waiting.popleft()
            start = self.start_time(header.stamp)
            self._work = self._checker.submit(self._prepare, data, sender, received, start,
                                              self.driver.setpoint_at(start, received))
        return done

    def start_time(self, stamp: tuple[int, int]) -> float | None:
        """A header stamp (sec, nanosec) on the drives' clock; None for the zero stamp."""
        if stamp == (0, 0):
            return None
        return (stamp[0] * 1_000_000_000 + stamp[1] - self.epoch_ns) * 1e-9

    def _prepare(self, data: bytes, sender: str, received: float, start: float | None,
                 setpoint: tuple[FloatArray, FloatArray]) -> Prepared | Outcome:
        """On the checker thread: decode, then every check of :meth:`LegDriver.prepare`."""
        try:
            msg = decode_joint_trajectory(data, self.driver.settings.command.max_points)
        except TrajectoryWireError as err:
            code = Refusal.TOO_MANY_POINTS if 'max_points' in str(err) else Refusal.INVALID_GOAL
            return Outcome(False, f'trajectory refused: not a trajectory the drives take: '
                                  f'{err}', '', code)
        return self.driver.prepare(msg.joint_names, msg.times, msg.positions, msg.velocities,
                                   start, received, sender, setpoint)

    def close(self) -> None:
        """Stop the checker thread (what it checks is not applied)."""
        self._checker.shutdown(wait=False, cancel_futures=True)
