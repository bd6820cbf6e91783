"""From recorded messages to calibration data: the same rule live (``calibrate_cell`` on the
messages it receives) and offline (``calibrate_cell --from-bag`` on a recording of them), so
both give the same result from the same data.

A calibration run marks each measured pose on ``/cell/calibration`` (std_msgs/String, JSON of
:class:`Marker`): once the positioner reports the move done, the procedure
(:mod:`positioning_cell.procedures.calibration`) takes ``samples`` tracker readings stamped
from ``start`` (s, the cell's clock) on, then sends the marker with that ``start``. The
pose's data are the first
``samples`` tracker poses (/metrology/pose) stamped at or after ``start``: their mean pose,
and their mean covariance divided by ``samples``; and every encoder reading
(/legs/joint_states) stamped from ``start`` to the last of those tracker stamps: their mean,
with the standard error of the mean (at least ``joint_sigma_floor``, the encoders'
resolution: a reading that does not change still carries its quantisation).

Each pose's conditions (:class:`~positioning_cell.calibration.identify.CalibrationData`
``temperature`` and ``approach``), by one rule for the live run and the bag
(:func:`pose_conditions`):

- temperature: the mean of the air-temperature readings (/cell/air_temperature, the sensor's,
  °C) stamped within the pose's window (``start`` to the last tracker stamp); without one,
  the latest reading before the window if it is at most :data:`TEMPERATURE_AGE` s older than
  ``start``; else none, and the run's ``temperature`` is None (:attr:`Collected.missing`
  says why);
- approach: per axis, the side the axis came from, +1 from below (increasing), −1 from above,
  0 when it never moved: the sign of (the pose's mean encoder value − the last encoder
  reading before the window that is more than :data:`APPROACH_THRESHOLD` away from it). The
  threshold is ten encoder counts, well above the encoders' noise and dither, far below a
  move. The look-back is the stream since the previous measured pose's ``start`` (before the
  first: the whole stream; live, from the calibration's homing on); an axis that stayed
  within the threshold over it keeps the previous pose's approach. (What the live run holds
  of the encoder stream between two poses is enough: the ROS port keeps 30 s of it.)
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.identify import CalibrationData
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Registration, averaged_covariance
from positioning_cell.moves.correction import mean_pose

FloatArray = NDArray[np.float64]

FIT, HOLD_OUT = 'fit', 'hold_out'
#: The encoders' resolution as a standard uncertainty (1 µm and 2^20 counts per turn, /√12):
#: the least uncertainty of a pose's mean encoder values.
JOINT_SIGMA_FLOOR = np.r_[[1e-6 / np.sqrt(12)] * 3, [2 * np.pi / 2**20 / np.sqrt(12)] * 3]
#: A motion of an axis that counts for its approach direction: more than ten encoder counts
#: (10 µm, 10 · 2π/2^20 rad) from where it stands at the pose; the encoders' noise and a
#: settled servo's dither stay within one or two counts.
APPROACH_THRESHOLD = 10.0 * np.sqrt(12) * JOINT_SIGMA_FLOOR
#: The oldest air-temperature reading (s before a pose's window) that still stands for the
#: pose when none is stamped within the window (the sensor publishes at 1 Hz; the air drifts
#: about 0.01 K in 60 s).
TEMPERATURE_AGE = 60.0


@dataclass(frozen=True)
class Marker:
    """One measured pose of a calibration run: the ``run`` it belongs to (its start, UTC ISO
    8601: a bag may hold several), its index in the program, its ``set`` (fit or hold_out),
    the commanded pose (base frame, m, x y z w), when the readings start (s) and how many
    tracker readings it takes."""

    run: str
    pose: int
    set: str
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    start: float
    samples: int

    def to_json(self) -> str:
        """The JSON text published on /cell/calibration."""
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Marker:
        """A marker from its JSON (InputError naming what is wrong)."""
        try:
            d = json.loads(text)
            marker = cls(str(d['run']), int(d['pose']), str(d['set']),
                         tuple(map(float, d['position'])),  # type: ignore[arg-type]
                         tuple(map(float, d['quaternion'])),  # type: ignore[arg-type]
                         float(d['start']), int(d['samples']))
        except (ValueError, KeyError, TypeError) as err:
            raise InputError(f'not a calibration marker: {text[:80]!r} ({err})') from None
        if marker.set not in (FIT, HOLD_OUT) or marker.samples < 1:
            raise InputError(f'not a calibration marker: {text[:80]!r}')
        return marker


class Stream(NamedTuple):
    """Stamped messages of one topic: ``stamps`` (M,) s and the values (M, ...)."""

    stamps: FloatArray
    values: tuple[FloatArray, ...]


class Collected(NamedTuple):
    """The data of a run's fit poses and hold-out poses, the commanded poses of each
    (position (N, 3), quaternion (N, 4)), the markers left out (with why), and why a
    condition of the poses is not in the data (``missing``: a sentence each)."""

    fit: CalibrationData
    fit_commanded: tuple[FloatArray, FloatArray]
    hold_out: CalibrationData
    hold_out_commanded: tuple[FloatArray, FloatArray]
    skipped: tuple[tuple[Marker, str], ...]
    missing: tuple[str, ...] = ()


def runs(markers: list[Marker]) -> list[str]:
    """The runs the markers belong to, in order of their first marker."""
    return list(dict.fromkeys(m.run for m in sorted(markers, key=lambda m: m.start)))


def _empty() -> CalibrationData:
    return CalibrationData(np.zeros((0, 6)), np.ones((0, 6)), np.zeros((0, 3)),
                           np.zeros((0, 4)), np.zeros((0, 6, 6)))


class Conditions(NamedTuple):
    """A pose's conditions (module docstring): the air temperature °C (None: no reading
    stands for it) and the approach direction (6,) ±1/0 of each axis."""

    temperature: float | None
    approach: FloatArray


class PoseData(NamedTuple):
    """One measured pose as calibration data: its marker, the mean encoder values (6,) and
    their standard uncertainty (6,), the mean tracker pose (3,) m / (4,) and its covariance
    (6, 6) (the readings' mean covariance divided by their number); its conditions (None: not
    taken) and the tracker registration it was measured through (None: not known)."""

    marker: Marker
    joints: FloatArray
    joint_sigma: FloatArray
    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    conditions: Conditions | None = None
    registration: Registration | None = None


def pose_data(marker: Marker, encoder_mean: ArrayLike, encoder_sem: ArrayLike,
              position: ArrayLike, quaternion: ArrayLike, covariance: ArrayLike,
              joint_sigma_floor: ArrayLike, conditions: Conditions | None = None,
              registration: Registration | None = None) -> PoseData:
    """The data of one pose (module docstring) from its ``marker.samples`` tracker readings
    (positions (k, 3) m, quaternions (k, 4), covariances (k, 6, 6)) and the mean (6,) and
    standard error of the mean (6,) of the encoder readings over the same window (the
    uncertainty at least ``joint_sigma_floor``), with its ``conditions``
    (:func:`pose_conditions`): the one rule of the live run and of a bag. The mean pose's
    covariance is :func:`~positioning_cell.metrology.instrument.averaged_covariance` with
    the part of every reading's covariance the tracker's ``registration`` gives at the mean
    position (None: not known, the readings taken as independent: the mean covariance / k)."""
    p_mean, q_mean = mean_pose(np.asarray(position, dtype=float),
                               np.asarray(quaternion, dtype=float))
    floor = np.broadcast_to(np.asarray(joint_sigma_floor, dtype=float), (6,))
    mean_cov = np.asarray(covariance, dtype=float).mean(axis=0)
    return PoseData(marker, np.asarray(encoder_mean, dtype=float),
                    np.maximum(np.asarray(encoder_sem, dtype=float), floor), p_mean, q_mean,
                    averaged_covariance(mean_cov, np.zeros((6, 6)) if registration is None
                                        else registration.covariance_at(p_mean)[0],
                                        marker.samples),
                    conditions, registration)


def window_temperature(stamps: ArrayLike, values: ArrayLike, start: float, end: float,
                       max_age: float = TEMPERATURE_AGE) -> float | None:
    """The air temperature °C of a window ``start`` … ``end`` s from readings (M,) °C
    stamped (M,) s in ascending order: their mean within the window, else the latest before
    it when at most ``max_age`` s older than ``start``, else None (module docstring)."""
    t = np.asarray(stamps, dtype=float)
    v = np.asarray(values, dtype=float)
    first = int(np.searchsorted(t, start, side='left'))
    last = int(np.searchsorted(t, end, side='right'))
    if last > first:
        return float(v[first:last].mean())
    if first > 0 and start - t[first - 1] <= max_age:
        return float(v[first - 1])
    return None


def approach_signs(stamps: ArrayLike, values: ArrayLike, start: float, joints: ArrayLike,
                   prior: ArrayLike, threshold: ArrayLike = APPROACH_THRESHOLD) -> FloatArray:
    """The approach direction (6,) ±1 of each axis at a pose (module docstring): the sign of
    ``joints`` (6,) (the pose's mean encoder values, m and rad) minus the last encoder reading
    (of ``values`` (M, 6) stamped ``stamps`` (M,) s ascending) stamped up to ``start`` s that
    is more than ``threshold`` (6,) away from it; ``prior`` (6,) for an axis without one."""
    t = np.asarray(stamps, dtype=float)
    v = np.asarray(values, dtype=float).reshape(-1, 6)[:int(np.searchsorted(t, start,
                                                                             side='right'))]
    x = np.asarray(joints, dtype=float)
    far = np.abs(v - x) > np.asarray(threshold, dtype=float)
    last = np.where(far, np.arange(v.shape[0])[:, None], -1).max(axis=0, initial=-1)
    away = v[np.maximum(last, 0), np.arange(6)] if v.shape[0] else np.zeros(6)
    out: FloatArray = np.where(last >= 0, np.sign(x - away),
                               np.asarray(prior, dtype=float))
    return out


def pose_conditions(encoders: Stream, temperatures: Stream | None, start: float, end: float,
                    joints: ArrayLike, prior: ArrayLike | None) -> Conditions:
    """A pose's conditions (module docstring) from the encoder readings (values (M, 6))
    since the previous pose's ``start`` and the air-temperature readings (values (K,) °C;
    None: none recorded), both in ascending stamps; the pose's window ``start`` … ``end`` s,
    its mean encoder values ``joints`` (6,) and the previous pose's approach ``prior`` (6,)
    (None: the first pose)."""
    temperature = None if temperatures is None else window_temperature(
        temperatures.stamps, temperatures.values[0], start, end)
    approach = approach_signs(encoders.stamps, encoders.values[0], start, joints,
                              np.zeros(6) if prior is None else prior)
    return Conditions(temperature, approach)


def encoder_window(values: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The mean (6,) of encoder readings (n, 6) over a pose's window and its standard error
    (std / √n)."""
    v = np.asarray(values, dtype=float).reshape(-1, 6)
    return v.mean(axis=0), v.std(axis=0) / np.sqrt(v.shape[0])


def assemble(poses: list[PoseData], skipped: tuple[tuple[Marker, str], ...] = ()) -> Collected:
    """The run's data from its measured poses, fit and hold-out apart, in their order; a
    condition only when every pose has it (else :attr:`Collected.missing` says why)."""
    conditions = [p.conditions for p in poses]
    missing: list[str] = []
    if not poses or any(c is None for c in conditions):
        missing.append('the conditions of the poses were not taken')
        temperature = approach = False
    else:
        cold = sum(1 for c in conditions if c is not None and c.temperature is None)
        temperature, approach = cold == 0, True
        if cold:
            missing.append(f'temperature: {cold} of {len(poses)} poses without an '
                           f'air-temperature reading in their window or the '
                           f'{TEMPERATURE_AGE:.0f} s before')

    def data(which: str) -> CalibrationData:
        rows = [p for p in poses if p.marker.set == which]
        if not rows:
            return _empty()
        got = CalibrationData(*(np.stack([getattr(r, f) for r in rows])
                                for f in ('joints', 'joint_sigma', 'position', 'quaternion',
                                          'covariance')))
        cond = [r.conditions for r in rows if r.conditions is not None]
        located = [r.registration for r in rows if r.registration is not None]
        return got._replace(
            temperature=np.array([c.temperature for c in cond], dtype=float)
            if temperature else None,
            approach=np.stack([c.approach for c in cond]) if approach else None,
            registration_origin=np.stack([g.position for g in located])
            if len(located) == len(rows) else None,
            registration_covariance=np.stack([g.covariance for g in located])
            if len(located) == len(rows) else None)

    def cmd(which: str) -> tuple[FloatArray, FloatArray]:
        rows = [p.marker for p in poses if p.marker.set == which]
        if not rows:
            return np.zeros((0, 3)), np.zeros((0, 4))
        return (np.array([m.position for m in rows], dtype=float),
                np.array([m.quaternion for m in rows], dtype=float))

    return Collected(data(FIT), cmd(FIT), data(HOLD_OUT), cmd(HOLD_OUT), skipped,
                     tuple(missing))


def registration_at(registrations: Sequence[tuple[float, Registration]],
                    start: float) -> Registration | None:
    """The registration in force at ``start`` s: the newest of ``registrations`` (stamp s,
    registration) stamped up to it, else the first (None: none)."""
    before = [entry for entry in registrations if entry[0] <= start]
    if before:
        return max(before, key=lambda entry: entry[0])[1]
    return min(registrations, key=lambda entry: entry[0])[1] if registrations else None


def in_order(stream: Stream) -> Stream:
    """The stream's messages in ascending stamps (stable: equal stamps keep their order)."""
    order = np.argsort(stream.stamps, kind='stable')
    return Stream(stream.stamps[order], tuple(v[order] for v in stream.values))


def collect(markers: list[Marker], joints: Stream, poses: Stream,
            joint_sigma_floor: ArrayLike, temperatures: Stream | None = None,
            registrations: Sequence[tuple[float, Registration]] = ()) -> Collected:
    """Calibration data from the markers and the joint (values: positions (M, 6)), tracker
    (values: position (K, 3), quaternion (K, 4), covariance (K, 6, 6)) and air-temperature
    (values: (L,) °C; None: not recorded) streams (module docstring), and the tracker's
    registrations (stamp s, registration; each pose takes the newest stamped up to its start,
    else the first: the part of its readings' covariance common to all of them; none: the
    readings taken as independent). Markers without enough readings are skipped, with the
    reason."""
    j_t, (j_v,) = in_order(joints)
    p_t, (p_p, p_q, p_c) = in_order(poses)
    air = None if temperatures is None else in_order(temperatures)
    measured: list[PoseData] = []
    skipped: list[tuple[Marker, str]] = []
    previous: tuple[float, FloatArray | None] = (-np.inf, None)
    for marker in sorted(markers, key=lambda m: m.start):
        first = int(np.searchsorted(p_t, marker.start, side='left'))
        take = slice(first, first + marker.samples)
        if p_t[take].size < marker.samples:
            skipped.append((marker, f'{p_t[take].size} of {marker.samples} tracker readings'))
            continue
        end = p_t[take][-1]
        in_window = (j_t >= marker.start) & (j_t <= end)
        if not in_window.any():
            skipped.append((marker, 'no encoder reading while it was measured'))
            continue
        mean, sem = encoder_window(j_v[in_window])
        since = int(np.searchsorted(j_t, previous[0], side='left'))
        conditions = pose_conditions(Stream(j_t[since:], (j_v[since:],)), air, marker.start,
                                     float(end), mean, previous[1])
        previous = (marker.start, conditions.approach)
        measured.append(pose_data(marker, mean, sem, p_p[take], p_q[take], p_c[take],
                                  joint_sigma_floor, conditions,
                                  registration_at(registrations, marker.start)))
    return assemble(measured, tuple(skipped))
