"""A stop along the path (issue 27): the running trajectory's time law slowed to rest, every
setpoint on the path it was following.

A drive's own controlled stop (:func:`~positioning_cell.sim.paths.stop_path`) decelerates each
axis along its joint-space tangent, each positioner on its own: the platforms leave the path,
and a panel held by several positioners is strained by their disagreement (seen: 902 N
between two attachments of the shipped three-positioner cell, 0.37 s after a stop of all).
Stopped along the path instead, from one instant ``t0`` and over one ``duration`` T, every
positioner of a coordinated move (one time law, one duration) stays where the rigid panel
puts it: each is at the same fraction of its move at every instant, as in the move itself.

The path time τ runs at a rate that falls linearly from 1 to 0 over T:
τ(t) = τ0 + t − t²/(2T) for 0 ≤ t ≤ T, τ0 the move's time at t0, so the stop covers T/2 s of
the move and the setpoints decelerate at their path speed / T (added to what the move's own
curvature asks). The joints follow the move's points as the drives interpolate them (cubic
Hermite of positions and rates, :class:`~positioning_cell.sim.paths.JointPath`): the stop
joins the running motion at t0 in position and velocity.

A positioner that hears of the stop only after t0 (its node held up) cannot slow from t0; it
stops at the same point of its path instead (:func:`joined_late`), so that once at rest the
platforms are again where the rigid panel puts them: δ late, its rate falls from 1 to 0 over
T − 2δ (covering (T − 2δ)/2 = T/2 − δ of path time from τ0 + δ), unless it is T/2 late or
more (then it has passed that point: it stops at once).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from positioning_cell.core.poses import interpolated_poses
from positioning_cell.errors import InputError
from positioning_cell.moves.trajectory import Trajectory
from positioning_cell.sim.paths import JointPath

#: A late positioner's stop starts at least this far ahead of when it is computed, s: sent
#: before it starts, the drives join it where it begins.
JOIN_LEAD = 0.02
#: The shortest stop worth joining, s (shorter: stopped at once).
SHORTEST = 0.01
#: Points of the stop per second of it, at least :data:`MIN_POINTS`: 100 Hz, the moves' own
#: sample rate order (the drives interpolate between them).
POINTS_PER_SECOND = 100.0
MIN_POINTS = 5


def stop_along_path(traj: Trajectory, elapsed: float, duration: float) -> Trajectory:
    """The stop of ``traj`` along its path from ``elapsed`` s after its start, at rest after
    ``duration`` s (module docstring): a :class:`Trajectory` whose times run from the stop's
    start, poses on ``traj``'s path (positions linear between its samples, quaternions their
    normalised blend: :func:`~positioning_cell.core.poses.interpolated_poses`) and joints as the
    drives interpolate ``traj``, their rates scaled by the path rate (zero at the end). Held at
    the move's ends: a stop that would reach past the goal ends at the goal. InputError for a
    duration that is not a positive number of seconds or an ``elapsed`` that is not finite."""
    if not (math.isfinite(duration) and duration > 0.0):
        raise InputError(f'duration = {duration!r}: a stop needs a positive number of seconds')
    if not math.isfinite(elapsed):
        raise InputError(f'elapsed = {elapsed!r}: not a number of seconds')
    n = max(MIN_POINTS, math.ceil(duration * POINTS_PER_SECOND) + 1)
    t = np.linspace(0.0, duration, n)
    rate = 1.0 - t / duration
    tau = np.clip(elapsed + t - t * t / (2.0 * duration), traj.times[0], traj.times[-1])
    inside = (tau > traj.times[0]) & (tau < traj.times[-1])
    joints = JointPath(traj.times, np.hstack([traj.lengths, traj.thetas]),
                       np.hstack([traj.length_rates, traj.theta_rates]))
    position_q, velocity_q = joints.sample(tau)
    velocity_q *= (rate * inside)[:, np.newaxis]
    position, quaternion = interpolated_poses(traj.times, traj.position, traj.quaternion, tau)
    return replace(traj, times=t, position=position, quaternion=quaternion,
                   lengths=position_q[:, :3], thetas=position_q[:, 3:],
                   length_rates=velocity_q[:, :3], theta_rates=velocity_q[:, 3:])


def until_stopped(traj: Trajectory, elapsed: float, stop: Trajectory) -> Trajectory:
    """``traj`` until ``elapsed`` s, then ``stop`` (:func:`stop_along_path` from there): what
    the drives follow once the stop is sent, on ``traj``'s time base (the setpoint the
    positioner publishes, the encoders' freeze watch)."""
    before = traj.times < elapsed
    parts = [(getattr(traj, name)[before], getattr(stop, name))
             for name in ('position', 'quaternion', 'lengths', 'thetas', 'length_rates',
                          'theta_rates')]
    joined = [np.concatenate(pair) for pair in parts]
    return replace(traj, times=np.concatenate([traj.times[before], elapsed + stop.times]),
                   position=joined[0], quaternion=joined[1], lengths=joined[2],
                   thetas=joined[3], length_rates=joined[4], theta_rates=joined[5])


def joined_late(start: float, duration: float, earliest: float) -> tuple[float, float] | None:
    """The stop from ``start`` over ``duration`` s (module docstring) for a positioner that can
    begin it no earlier than ``earliest`` (the same clock; it has followed its move until
    then): (start, duration) unchanged when ``earliest`` ≤ ``start``; else from ``earliest``
    over ``duration`` − 2·(``earliest`` − ``start``), to the same point of the path; None when
    that leaves less than :data:`SHORTEST` (stop at once)."""
    late = max(earliest - start, 0.0)
    remaining = duration - 2.0 * late
    if remaining < SHORTEST:
        return None
    return start + late, remaining
