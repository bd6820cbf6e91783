"""From recorded messages to calibration data: the same rule live (``calibrate_cell`` on the
messages it receives) and offline (``calibrate_cell --from-bag`` on a recording of them), so
both give the same result from the same data.

A calibration run marks each measured pose on ``/cell/calibration`` (std_msgs/String, JSON of
:class:`Marker`): once the positioner reports the move done, the tool stamps ``start`` (s,
the cell's clock) and asks for ``samples`` tracker readings. The pose's data are the first
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


def collect(markers: list[Marker], joints: Stream, poses: Stream,
            joint_sigma_floor: ArrayLike) -> Collected:
    """Calibration data from the markers and the joint (values: positions (M, 6)) and tracker
    (values: position (K, 3), quaternion (K, 4), covariance (K, 6, 6)) streams (module
    docstring). Markers without enough readings are skipped, with the reason."""
    floor = np.broadcast_to(np.asarray(joint_sigma_floor, dtype=float), (6,))
    j_order = np.argsort(joints.stamps, kind='stable')
    j_t = joints.stamps[j_order]
    j_v = joints.values[0][j_order]
    p_order = np.argsort(poses.stamps, kind='stable')
    p_t = poses.stamps[p_order]
    p_p, p_q, p_c = (v[p_order] for v in poses.values)
    rows: dict[str, list[tuple[FloatArray, ...]]] = {FIT: [], HOLD_OUT: []}
    commanded: dict[str, list[tuple[FloatArray, FloatArray]]] = {FIT: [], HOLD_OUT: []}
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
        values = j_v[in_window]
        sem = values.std(axis=0) / np.sqrt(values.shape[0])
        p_mean, q_mean = mean_pose(p_p[take], p_q[take])
        rows[marker.set].append((values.mean(axis=0), np.maximum(sem, floor), p_mean, q_mean,
                                 p_c[take].mean(axis=0) / marker.samples))
        commanded[marker.set].append((np.asarray(marker.position),
                                      np.asarray(marker.quaternion)))

    def data(which: str) -> CalibrationData:
        if not rows[which]:
            return _empty()
        return CalibrationData(*(np.stack(col) for col in zip(*rows[which], strict=True)))

    def cmd(which: str) -> tuple[FloatArray, FloatArray]:
        if not commanded[which]:
            return np.zeros((0, 3)), np.zeros((0, 4))
        p, q = zip(*commanded[which], strict=True)
        return np.stack(p), np.stack(q)

    return Collected(data(FIT), cmd(FIT), data(HOLD_OUT), cmd(HOLD_OUT), tuple(skipped))
