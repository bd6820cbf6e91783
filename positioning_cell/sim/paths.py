"""Setpoint paths of the six axes: the trajectory sampler the servos follow (cubic Hermite of
the trajectory points), holds and controlled stops, and the conversion of trajectory points
(trajectory_msgs/JointTrajectory fields) into a path. Units: m, rad, s."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import InputError
from positioning_cell.sim.axes import AXES, unit_of

FloatArray = NDArray[np.float64]
#: Trajectory point times (K,) s, as a message's list or a decoded array.
Times = Sequence[float] | FloatArray
#: Per point values (K, n), as a message's lists or a decoded array.
Points = Sequence[Sequence[float]] | FloatArray


class JointNamesError(InputError):
    """A trajectory's joint names are not the six axes (unknown, duplicate or missing)."""

# -- setpoint paths --------------------------------------------------------------------------
@dataclass(frozen=True)
class JointPath:
    """Setpoints of the six axes: points at ``times`` (M,) s from the path's start (finite,
    ≥ 0, strictly increasing), ``positions`` (M, 6) in m / rad and ``velocities`` (M, 6) in
    m/s / rad/s, or None for linear interpolation. Between points the setpoint is the cubic
    Hermite interpolant of positions and velocities (or linear); before the first point it is
    the first point, after the last one it holds the last position with zero velocity."""

    times: FloatArray
    positions: FloatArray
    velocities: FloatArray | None = None

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        if times.ndim != 1 or times.size == 0 or not np.isfinite(times).all():
            raise InputError(f'times: expected M >= 1 finite values, got {self.times!r}')
        if times[0] < 0.0 or (np.diff(times) <= 0.0).any():
            raise InputError(f'times must be >= 0 and strictly increasing, got {times.tolist()}')
        object.__setattr__(self, 'times', times)
        for name in ('positions', 'velocities'):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.shape != (times.size, AXES) or not np.isfinite(arr).all():
                raise InputError(f'{name}: expected {times.size} finite rows of {AXES}, '
                                 f'got shape {arr.shape}')
            object.__setattr__(self, name, arr)

    @property
    def duration(self) -> float:
        """Time of the last point, s."""
        return float(self.times[-1])

    @property
    def final(self) -> FloatArray:
        """The last point's positions (6,)."""
        final: FloatArray = self.positions[-1]
        return final

    def sample(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Setpoint positions and feed-forward velocities (K, 6) at times ``t`` (K,) s from
        the path's start: on the segment [t_i, t_i+1) that holds t (the last one closed), with
        h = t_i+1 − t_i and s = (t − t_i) / h, the cubic Hermite interpolant
        p = h00(s) p_i + h h10(s) v_i + h01(s) p_i+1 + h h11(s) v_i+1 (h00 = 2s³ − 3s² + 1,
        h10 = s³ − 2s² + s, h01 = −2s³ + 3s², h11 = s³ − s²) and its derivative; linear when
        the path has no velocities. Plain numpy (scipy.interpolate's CubicHermiteSpline and
        linear spline give the same: test_paths; its import cost the driver ~0.3 s at start)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.times.size == 1 or bool(np.all(t >= self.times[-1])):
            # held: the last position at rest (the driver's every step once a path is over)
            return np.tile(self.positions[-1], (t.size, 1)), np.zeros((t.size, AXES))
        clipped = np.clip(t, self.times[0], self.times[-1])
        i = np.clip(np.searchsorted(self.times, clipped, side='right') - 1, 0,
                    self.times.size - 2)
        h = (self.times[i + 1] - self.times[i])[:, np.newaxis]
        s = (clipped - self.times[i])[:, np.newaxis] / h
        p0, p1 = self.positions[i], self.positions[i + 1]
        if self.velocities is None:
            position: FloatArray = p0 + s * (p1 - p0)
            velocity: FloatArray = (p1 - p0) / h
        else:
            v0, v1 = self.velocities[i], self.velocities[i + 1]
            s2 = s * s
            s3 = s2 * s
            position = ((2.0 * s3 - 3.0 * s2 + 1.0) * p0 + (s3 - 2.0 * s2 + s) * h * v0
                        + (3.0 * s2 - 2.0 * s3) * p1 + (s3 - s2) * h * v1)
            velocity = ((6.0 * s2 - 6.0 * s) * (p0 - p1) / h + (3.0 * s2 - 4.0 * s + 1.0) * v0
                        + (3.0 * s2 - 2.0 * s) * v1)
        velocity[(t < self.times[0]) | (t >= self.times[-1])] = 0.0
        return position, velocity

    def starting_from(self, position: FloatArray, velocity: FloatArray) -> JointPath:
        """This path with the point (``position``, ``velocity``) put at t = 0 when its first
        point is later (how a new trajectory joins the current motion)."""
        if self.times[0] == 0.0:
            return self
        velocities = (None if self.velocities is None
                      else np.vstack([velocity, self.velocities]))
        return JointPath(np.concatenate([[0.0], self.times]),
                         np.vstack([position, self.positions]), velocities)

def hold_path(position: ArrayLike) -> JointPath:
    """A path that holds ``position`` (6,)."""
    return JointPath(np.zeros(1), np.reshape(np.asarray(position, dtype=float), (1, AXES)),
                     np.zeros((1, AXES)))

def stop_path(position: ArrayLike, velocity: ArrayLike, acceleration: ArrayLike) -> JointPath:
    """Controlled stop from (``position``, ``velocity``) (6,): all axes decelerate uniformly and
    stop together after T = max_i |v_i| / a_i, so no axis exceeds its deceleration a_i (6,) and
    the joint-space direction of motion is kept. The axis that sets T stops after v²/(2a), the
    others after v_i T / 2 (≥ v_i²/(2 a_i)). The setpoint is quadratic in t (the cubic Hermite
    of the two points is exactly that quadratic)."""
    p = np.asarray(position, dtype=float)
    v = np.asarray(velocity, dtype=float)
    stop_time = float(np.max(np.abs(v) / np.asarray(acceleration, dtype=float)))
    if stop_time <= 0.0:
        return hold_path(p)
    return JointPath(np.array([0.0, stop_time]), np.vstack([p, p + 0.5 * v * stop_time]),
                     np.vstack([v, np.zeros(AXES)]))

def path_from_points(names: Sequence[str], times: Times, positions: Points, velocities: Points,
                     v_max: FloatArray | None = None) -> JointPath:
    """A JointPath from trajectory points (trajectory_msgs/JointTrajectory): ``names`` the six
    JOINT_NAMES in any order; per point k its time_from_start ``times[k]`` (s), ``positions[k]``
    and ``velocities[k]`` (one value per name; velocities empty on every point = linear
    interpolation; decoded arrays (K, 6) take the same checks without a loop over points).
    Columns are reordered to JOINT_NAMES. With ``v_max`` (6,), point velocities
    and mean segment velocities above it are refused. Raises InputError naming the problem.
    """
    names = list(names)
    unknown = sorted(set(names) - set(JOINT_NAMES))
    if unknown:
        raise JointNamesError(f'unknown joint names {unknown}; expected {list(JOINT_NAMES)}')
    if len(set(names)) != len(names):
        raise JointNamesError(f'duplicate joint names in {names}')
    missing = [n for n in JOINT_NAMES if n not in names]
    if missing:
        raise JointNamesError(f'joint names {missing} missing; all six axes are commanded '
                              'together')
    if len(times) == 0:
        raise InputError('a trajectory needs at least one point (an empty one stops)')
    if isinstance(positions, np.ndarray) and positions.ndim == 2:  # decoded: one layout
        if positions.shape[1] != AXES:
            raise InputError(f'point 0 has {positions.shape[1]} positions, expected {AXES}')
    else:
        for k, row in enumerate(positions):
            if len(row) != AXES:
                raise InputError(f'point {k} has {len(row)} positions, expected {AXES}')
    if isinstance(velocities, np.ndarray) and velocities.ndim == 2:
        given = [velocities.shape[1]] * len(velocities)
    else:
        given = [len(row) for row in velocities]
    if any(n not in (0, AXES) for n in given) or 0 < given.count(AXES) < len(given):
        raise InputError(f'velocities: give {AXES} on every point or none, got counts '
                         f'{given if len(given) <= 20 else sorted(set(given))}')
    order = [names.index(n) for n in JOINT_NAMES]
    pos = np.asarray(positions, dtype=float)[:, order]
    vel = np.asarray(velocities, dtype=float)[:, order] if given and given[0] else None
    _check_finite(times, pos, vel)
    path = JointPath(np.asarray(times, dtype=float), pos, vel)
    if v_max is not None:
        _check_speeds(path, v_max)
    return path

def _check_finite(times: Times, positions: FloatArray,
                  velocities: FloatArray | None) -> None:
    """InputError for a NaN or infinite number, naming the point and the axis."""
    t = np.asarray(times, dtype=float)
    if not np.isfinite(t).all():
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise InputError(f'point {k}: time_from_start is {t[k]}')
    for what, values in (('', positions), (' velocity', velocities)):
        if values is not None and not np.isfinite(values).all():
            k, axis = (int(i) for i in np.argwhere(~np.isfinite(values))[0])
            kind = 'NaN' if np.isnan(values[k, axis]) else 'infinite'
            raise InputError(f'point {k}, {JOINT_NAMES[axis]}{what} is {kind}')


def _check_speeds(path: JointPath, v_max: FloatArray) -> None:
    speeds = np.abs(np.diff(path.positions, axis=0) / np.diff(path.times)[:, None])
    if path.velocities is not None:
        speeds = np.vstack([speeds, np.abs(path.velocities)])
    over = speeds > v_max * (1.0 + 1e-9)
    if over.any():
        axis = int(np.flatnonzero(over.any(axis=0))[0])
        unit = unit_of(axis, 1)
        raise InputError(f'{JOINT_NAMES[axis]} speed {speeds[:, axis].max():.6g} {unit} '
                         f'exceeds its limit {v_max[axis]:.6g} {unit}')
