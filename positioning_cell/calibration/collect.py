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
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.identify import CalibrationData
from positioning_cell.errors import InputError
from positioning_cell.moves.correction import mean_pose

FloatArray = NDArray[np.float64]

FIT, HOLD_OUT = 'fit', 'hold_out'
#: The encoders' resolution as a standard uncertainty (1 µm and 2^20 counts per turn, /√12):
#: the least uncertainty of a pose's mean encoder values.
JOINT_SIGMA_FLOOR = np.r_[[1e-6 / np.sqrt(12)] * 3, [2 * np.pi / 2**20 / np.sqrt(12)] * 3]


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
    (position (N, 3), quaternion (N, 4)), and the markers left out (with why)."""

    fit: CalibrationData
    fit_commanded: tuple[FloatArray, FloatArray]
    hold_out: CalibrationData
    hold_out_commanded: tuple[FloatArray, FloatArray]
    skipped: tuple[tuple[Marker, str], ...]


def runs(markers: list[Marker]) -> list[str]:
    """The runs the markers belong to, in order of their first marker."""
    return list(dict.fromkeys(m.run for m in sorted(markers, key=lambda m: m.start)))


def _empty() -> CalibrationData:
    return CalibrationData(np.zeros((0, 6)), np.ones((0, 6)), np.zeros((0, 3)),
                           np.zeros((0, 4)), np.zeros((0, 6, 6)))


class PoseData(NamedTuple):
    """One measured pose as calibration data: its marker, the mean encoder values (6,) and
    their standard uncertainty (6,), the mean tracker pose (3,) m / (4,) and its covariance
    (6, 6) (the readings' mean covariance divided by their number)."""

    marker: Marker
    joints: FloatArray
    joint_sigma: FloatArray
    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray


def pose_data(marker: Marker, encoder_mean: ArrayLike, encoder_sem: ArrayLike,
              position: ArrayLike, quaternion: ArrayLike, covariance: ArrayLike,
              joint_sigma_floor: ArrayLike) -> PoseData:
    """The data of one pose (module docstring) from its ``marker.samples`` tracker readings
    (positions (k, 3) m, quaternions (k, 4), covariances (k, 6, 6)) and the mean (6,) and
    standard error of the mean (6,) of the encoder readings over the same window (the
    uncertainty at least ``joint_sigma_floor``): the one rule of the live run and of a bag."""
    p_mean, q_mean = mean_pose(np.asarray(position, dtype=float),
                               np.asarray(quaternion, dtype=float))
    floor = np.broadcast_to(np.asarray(joint_sigma_floor, dtype=float), (6,))
    return PoseData(marker, np.asarray(encoder_mean, dtype=float),
                    np.maximum(np.asarray(encoder_sem, dtype=float), floor), p_mean, q_mean,
                    np.asarray(covariance, dtype=float).mean(axis=0) / marker.samples)


def encoder_window(values: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The mean (6,) of encoder readings (n, 6) over a pose's window and its standard error
    (std / √n)."""
    v = np.asarray(values, dtype=float).reshape(-1, 6)
    return v.mean(axis=0), v.std(axis=0) / np.sqrt(v.shape[0])


def assemble(poses: list[PoseData], skipped: tuple[tuple[Marker, str], ...] = ()) -> Collected:
    """The run's data from its measured poses, fit and hold-out apart, in their order."""
    def data(which: str) -> CalibrationData:
        rows = [p for p in poses if p.marker.set == which]
        if not rows:
            return _empty()
        return CalibrationData(*(np.stack([getattr(r, f) for r in rows])
                                 for f in ('joints', 'joint_sigma', 'position', 'quaternion',
                                           'covariance')))

    def cmd(which: str) -> tuple[FloatArray, FloatArray]:
        rows = [p.marker for p in poses if p.marker.set == which]
        if not rows:
            return np.zeros((0, 3)), np.zeros((0, 4))
        return (np.array([m.position for m in rows], dtype=float),
                np.array([m.quaternion for m in rows], dtype=float))

    return Collected(data(FIT), cmd(FIT), data(HOLD_OUT), cmd(HOLD_OUT), skipped)


def collect(markers: list[Marker], joints: Stream, poses: Stream,
            joint_sigma_floor: ArrayLike) -> Collected:
    """Calibration data from the markers and the joint (values: positions (M, 6)) and tracker
    (values: position (K, 3), quaternion (K, 4), covariance (K, 6, 6)) streams (module
    docstring). Markers without enough readings are skipped, with the reason."""
    j_order = np.argsort(joints.stamps, kind='stable')
    j_t = joints.stamps[j_order]
    j_v = joints.values[0][j_order]
    p_order = np.argsort(poses.stamps, kind='stable')
    p_t = poses.stamps[p_order]
    p_p, p_q, p_c = (v[p_order] for v in poses.values)
    measured: list[PoseData] = []
    skipped: list[tuple[Marker, str]] = []
    for marker in markers:
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
        measured.append(pose_data(marker, *encoder_window(j_v[in_window]), p_p[take],
                                  p_q[take], p_c[take], joint_sigma_floor))
    return assemble(measured, tuple(skipped))
