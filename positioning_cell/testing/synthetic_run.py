"""A synthetic recorded run, for the analysis tests and benchmark: commanded poses visited in
cycles under each compensation mode, the tracker's noisy measurements and the true poses,
written as an MCAP rosbag2 bag with the QoS the cell's publishers offer (reliable; the target
and the program latched): by the cell's writer (:class:`positioning_cell.bag.BagWriter`, what
the recorder writes: its chunk size, chunk and data-section CRCs) or by rosbags' writer
(``rosbags.rosbag2.Writer``: 1 MiB chunks, no CRCs).

Each move starts at its target's stamp; the platform travels for ``move_time`` s from the last
attained pose to the new one (commanded + the mode's bias + a random offset per visit) and
stays there until the next target. Measurements (``rate`` Hz) carry Gaussian noise; the true
pose is published with the same stamps, without noise.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosReliability
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from scipy.spatial.transform import Rotation

from positioning_cell.analysis.program import ProgramStep
from positioning_cell.bag.description import RUN_RECORD, MetadataRecord
from positioning_cell.bag.metadata import make_qos
from positioning_cell.bag.writer import DEFAULT_CHUNK_BYTES, BagWriter
from positioning_cell.calibration.collect import FIT, Marker
from positioning_cell.core.poses import as_pose_batch, quad, triple
from positioning_cell.names import (
    CALIBRATION,
    DIAGNOSTICS,
    JOINT_STATES,
    MEASURED_POSE,
    PROGRAM,
    STATUS_MEASUREMENT,
    STATUS_POSITIONER,
    TARGET,
    TRACKER_REGISTRATION,
    TRUE_POSE,
)

FloatArray = NDArray[np.float64]

#: Bias of the attained pose per mode: position (m) and rotation vector (rad), base frame.
DEFAULT_BIAS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    'none': ((400e-6, -250e-6, 150e-6), (4e-3, -6e-3, 2e-3)),
    'model': ((30e-6, 20e-6, -10e-6), (2e-4, 1e-4, -1e-4)),
    'measured': ((6e-6, -4e-6, 3e-6), (1e-5, -1e-5, 5e-6)),
}
#: Topics whose publishers are latched (transient-local) in the cell; the rest are streams.
LATCHED_TOPICS = (TARGET, PROGRAM, TRACKER_REGISTRATION)


@dataclass(frozen=True)
class SyntheticRun:
    """Targets (M,) s / (M, 3) m / (M, 4) with their program steps, measurements and true
    poses (N,) s / (N, 3) m / (N, 4), and when each move ended (M,) s (the positioner's
    report: the platform has arrived)."""

    target_time: FloatArray
    target_position: FloatArray
    target_quaternion: FloatArray
    steps: tuple[ProgramStep, ...]
    time: FloatArray
    position: FloatArray
    quaternion: FloatArray
    true_position: FloatArray
    true_quaternion: FloatArray
    end_time: FloatArray
    #: The covariance (6, 6) each measurement states (x, y, z, rot-x, rot-y, rot-z: m², rad²;
    #: the noise it carries, isotropic); None: zeros, an exact tracker.
    covariance: FloatArray | None = None


def synthetic_run(position: ArrayLike, quaternion: ArrayLike,
                  modes: Sequence[str] = ('none', 'model', 'measured'), cycles: int = 3,
                  *, rate: float = 20.0, move_time: float = 1.0, dwell_time: float = 2.5,
                  bias: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None,
                  visit_sigma: float = 5e-6, noise: float = 8e-6, angle_noise: float = 2e-5,
                  start: float = 1.7e9, seed: int = 0,
                  pause: Mapping[str, float] | None = None, pause_time: float = 1.0,
                  correction_time: float = 0.2) -> SyntheticRun:
    """The run: for each mode, ``cycles`` passes over the commanded poses (K, 3) m / (K, 4);
    a move every ``move_time + dwell_time`` s; noise sigmas in m and rad. ``pause`` {mode:
    offset m}: in that mode each move first stops ``offset`` off along x for ``pause_time`` s
    (the pause that measures, in ``measured`` compensation), then a correction brings the
    platform to its pose in ``correction_time`` s; the move ends after the correction."""
    rng = np.random.default_rng(seed)
    cp, cq = as_pose_batch(position, quaternion)
    bias = bias or DEFAULT_BIAS
    period = move_time + dwell_time
    steps: list[ProgramStep] = []
    times: list[float] = []
    targets: list[int] = []
    for mode in modes:
        for cycle in range(1, cycles + 1):
            for k in range(cp.shape[0]):
                t = start + 0.5 + len(targets) * period + 0.013
                steps.append(ProgramStep(mode, t - 0.2, cycle, f'P{k + 1}'))
                times.append(t)
                targets.append(k)
    index = np.array(targets)
    tt = np.array(times)
    b = np.array([bias[s.mode][0] for s in steps])
    rb = np.array([bias[s.mode][1] for s in steps])
    goal_p = cp[index] + b + rng.normal(0.0, visit_sigma, b.shape)
    goal_r = Rotation.from_quat(cq[index]) * Rotation.from_rotvec(
        rb + rng.normal(0.0, visit_sigma / 0.1, rb.shape))
    ts = start + np.arange(int((tt[-1] + period - start) * rate)) / rate
    seg = np.searchsorted(tt, ts, side='right') - 1
    prev = np.maximum(seg - 1, 0)
    frac = np.clip((ts - tt[np.maximum(seg, 0)]) / move_time, 0.0, 1.0)[:, None]
    frac[seg < 0] = 1.0
    s = np.maximum(seg, 0)
    pause_x = np.array([(pause or {}).get(step.mode, 0.0) for step in steps])
    held = np.where(pause_x > 0.0, pause_time + correction_time, 0.0)
    since = ts - tt[s] - move_time - pause_time  # into the correction (s)
    weight = np.where(since <= 0.0, frac[:, 0], np.clip(1.0 - since / correction_time, 0, 1))
    weight[seg < 0] = 0.0
    true_p = goal_p[prev] + (goal_p[s] - goal_p[prev]) * frac
    true_p[:, 0] += pause_x[s] * weight
    rel = (goal_r[prev].inv() * goal_r[s]).as_rotvec()
    true_r = goal_r[prev] * Rotation.from_rotvec(rel * frac)
    meas_p = true_p + rng.normal(0.0, noise, true_p.shape)
    meas_r = true_r * Rotation.from_rotvec(rng.normal(0.0, angle_noise, true_p.shape))
    return SyntheticRun(tt, cp[index], cq[index], tuple(steps), ts, meas_p,
                        meas_r.as_quat(canonical=True), true_p, true_r.as_quat(canonical=True),
                        tt + move_time + held,
                        np.diag([noise**2] * 3 + [angle_noise**2] * 3))


def _stamp(t: float) -> tuple[int, int]:
    sec = int(np.floor(t))
    return sec, round((t - sec) * 1e9) % 1_000_000_000


def write_run_bag(path: str | Path, run: SyntheticRun, *, truth: bool = True,
                  program: bool = True, diagnostics: bool = True,
                  joint_state_rate: float = 0.0, latency: float = 0.002,
                  truncate_to: float | None = None, writer: str = 'cell',
                  compression: str = 'none', chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                  latched_target_age: float = 0.0, calibration: str | None = None,
                  calibration_run: str | None = None,
                  registration_um: Sequence[float] | None = None,
                  variance_factor: float = 1.0, move_ends: bool = True,
                  tracker_registration: tuple[ArrayLike, ArrayLike] | None = None,
                  description: Mapping[str, str] | None = None) -> int:
    """Write ``run`` as a bag at ``path`` (must not exist): targets, measurements, and as
    asked the truth, the program steps, the positioner's mode diagnostics (a ``moving``
    status at each target and, with ``move_ends``, a ``settled`` one at each move's end) and
    filler
    /legs/joint_states at ``joint_state_rate`` Hz (same bytes, stamps patched). Log time =
    stamp + ``latency``; each measurement states the run's ``covariance``. ``writer``:
    ``cell`` (BagWriter, chunks of ``chunk_bytes``, CRCs) or
    ``rosbags`` (rosbags' writer, no CRCs); ``compression``: ``none`` or ``zstd`` chunks.
    ``latched_target_age`` > 0: the bag starts with the /positioner/target of an earlier move
    (the first target's pose, where the platform already is), stamped that many seconds
    before the first measurement and logged with it, as a recorder started after that move
    receives the latched target. ``truncate_to`` (0..1) then cuts the .mcap file to that
    fraction and removes metadata.yaml, as a killed recorder leaves it. The run's context, as
    asked: ``calibration``, the positioner's ``calibration`` value in each of its statuses
    (a file, or ``none``); ``calibration_run``: the /cell/calibration markers of a calibration
    run of that name, three poses at the first target's pose just after the first
    measurement; ``registration_um``: a tracker registration (residual of each base target,
    µm; their RMS and max, ``variance_factor``) in the pose_measurement diagnostics at the
    first and the last measurement; ``tracker_registration``: (origin (3,) m, covariance
    (6, 6)) on /metrology/registration (latched) just before the first measurement, as the
    tracker publishes where it located itself. ``description``: the run record's values the
    cell's recorder stores first (``writer='cell'`` only). Returns the messages written."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    Time, Header = T['builtin_interfaces/msg/Time'], T['std_msgs/msg/Header']
    Point, Quat = T['geometry_msgs/msg/Point'], T['geometry_msgs/msg/Quaternion']
    Pose = T['geometry_msgs/msg/Pose']

    def header(t: float) -> Any:
        return Header(stamp=Time(*_stamp(t)), frame_id='base')

    def status(name: str, message: str, values: Mapping[str, Any]) -> Any:
        return T['diagnostic_msgs/msg/DiagnosticStatus'](
            level=0, name=name, message=message, hardware_id='cell',
            values=[T['diagnostic_msgs/msg/KeyValue'](k, str(v)) for k, v in values.items()])

    def pose(p: FloatArray, q: FloatArray) -> Any:
        return Pose(position=Point(*(float(v) for v in p)),
                    orientation=Quat(*(float(v) for v in q)))

    events: list[tuple[float, str, str, Any]] = []
    stamped = 'geometry_msgs/msg/PoseStamped'
    if latched_target_age > 0:  # first in the list: sorts before the first measurement
        events.append((float(run.time[0]), TARGET, stamped, T[stamped](
            header(float(run.time[0]) - latched_target_age),
            pose(run.target_position[0], run.target_quaternion[0]))))
    for i, t in enumerate(run.target_time):
        events.append((t, TARGET, stamped, T[stamped](
            header(t), pose(run.target_position[i], run.target_quaternion[i]))))
    cov = 'geometry_msgs/msg/PoseWithCovarianceStamped'
    stated = np.zeros(36) if run.covariance is None else np.asarray(run.covariance).ravel()
    for i, t in enumerate(run.time):
        events.append((t, MEASURED_POSE, cov, T[cov](header(t), T[
            'geometry_msgs/msg/PoseWithCovariance'](pose(run.position[i], run.quaternion[i]),
                                                     stated))))
        if truth:
            events.append((t, TRUE_POSE, stamped, T[stamped](
                header(t), pose(run.true_position[i], run.true_quaternion[i]))))
    if tracker_registration is not None:
        origin, spread = (np.asarray(a, dtype=float) for a in tracker_registration)
        events.append((float(run.time[0]) - 0.01, TRACKER_REGISTRATION, cov, T[cov](
            header(float(run.time[0]) - 0.01), T['geometry_msgs/msg/PoseWithCovariance'](
                pose(origin, np.array([0.0, 0.0, 0.0, 1.0])), spread.ravel()))))
    string, diag = T['std_msgs/msg/String'], 'diagnostic_msgs/msg/DiagnosticArray'
    if program:
        events += [(s.stamp, PROGRAM, 'std_msgs/msg/String', string(s.to_json()))
                   for s in run.steps]
    if diagnostics:
        for s, t in zip(run.steps, run.target_time, strict=True):
            values = {'mode': s.mode} if calibration is None else {
                'mode': s.mode, 'calibration': calibration}
            events.append((t + 0.001, DIAGNOSTICS, diag, T[diag](header(t + 0.001), [
                status(STATUS_POSITIONER, 'moving', {**values, 'state': 'moving'})])))
        if move_ends:
            for s, t in zip(run.steps, run.end_time, strict=True):
                values = {'mode': s.mode, 'state': 'settled', 'code': 'success'}
                events.append((t, DIAGNOSTICS, diag, T[diag](header(t), [
                    status(STATUS_POSITIONER, 'settled: there', values)])))
    if registration_um is not None:
        r = np.asarray(registration_um, dtype=float)
        located: dict[str, Any] = {
            'locations': 1, 'locate_residual_rms_um': float(np.sqrt((r * r).mean())),
            'locate_residual_max_um': float(r.max()), 'locate_residuals_um': r.tolist(),
            'locate_variance_factor': variance_factor,
            'registration_sigma_position_um': [1.0, 1.0, 1.0],
            'registration_sigma_rotation_urad': [2.0, 2.0, 2.0]}
        events += [(float(t), DIAGNOSTICS, diag, T[diag](header(float(t)), [
            status(STATUS_MEASUREMENT, 'tracker located', located)]))
            for t in (run.time[0], run.time[-1])]
    if calibration_run is not None:
        for k in range(3):
            t = float(run.time[0]) + 0.01 * (k + 1)
            marker = Marker(calibration_run, k, FIT, triple(run.target_position[0]),
                            quad(run.target_quaternion[0]), t, 5)
            events.append((t, CALIBRATION, 'std_msgs/msg/String', string(marker.to_json())))
    filler = b''
    if joint_state_rate > 0:
        js = T['sensor_msgs/msg/JointState'](header(0.0), [f'j{k}' for k in range(6)],
                                             np.zeros(6), np.zeros(6), np.zeros(6))
        filler = bytes(store.serialize_cdr(js, 'sensor_msgs/msg/JointState'))
        ft = run.time[0] + np.arange(int((run.time[-1] - run.time[0]) * joint_state_rate)) / (
            joint_state_rate)
        events += [(float(t), JOINT_STATES, 'sensor_msgs/msg/JointState', filler)
                   for t in ft]
    events.sort(key=lambda e: e[0])
    path = Path(path)
    qos: dict[str, tuple[str, Qos]] = {}
    for _, topic, msgtype, _ in events:
        if topic not in qos:
            durability = (QosDurability.TRANSIENT_LOCAL if topic in LATCHED_TOPICS
                          else QosDurability.VOLATILE)
            qos[topic] = (msgtype, make_qos(QosHistory.KEEP_LAST,
                                            1 if topic in LATCHED_TOPICS else 100,
                                            QosReliability.RELIABLE, durability))

    def serialized() -> Iterator[tuple[str, str, bytes, int]]:
        for t, topic, msgtype, msg in events:
            if isinstance(msg, bytes):
                patched = bytearray(msg)
                struct.pack_into('<iI', patched, 4, *_stamp(t))
                raw = bytes(patched)
            else:
                raw = bytes(store.serialize_cdr(msg, msgtype))
            yield topic, msgtype, raw, round((t + latency) * 1e9)

    if writer == 'cell':
        with BagWriter(path, compression=compression, chunk_bytes=chunk_bytes) as bag:
            if description is not None:
                bag.describe([MetadataRecord(RUN_RECORD, description)])
            for topic, (msgtype, q) in qos.items():
                bag.add_topic(topic, msgtype, [q])
            for topic, msgtype, raw, log_ns in serialized():
                bag.write(topic, msgtype, raw, log_ns)
    elif writer == 'rosbags':
        other = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        if compression == 'zstd':
            other.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with other:
            conns = {topic: other.add_connection(topic, msgtype, typestore=store,
                                                 offered_qos_profiles=[q])
                     for topic, (msgtype, q) in qos.items()}
            for topic, _, raw, log_ns in serialized():
                other.write(conns[topic], log_ns, raw)
    else:
        raise ValueError(f'writer {writer!r}: expected cell or rosbags')
    if truncate_to is not None:
        (path / 'metadata.yaml').unlink()
        mcap = next(path.glob('*.mcap'))
        data = mcap.read_bytes()
        mcap.write_bytes(data[:int(len(data) * truncate_to)])
    return len(events)



#: The ISO 9283 cube of config/program.yaml: its centre and four points on its diagonal plane.
CUBE_POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                           [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])
#: A move every this many seconds in a long run (1 s moving, the rest still).
LONG_RUN_PERIOD = 2.5
#: Share of a recorded run's messages that /legs/joint_states is (the analysed topics are the
#: rest: ~13 %, 5 100 of 43 900 in a `make run` bag).
JOINT_STATE_SHARE = 0.87


def long_run(messages: int, *, start: float = 1.7e9, seed: int = 0,
             rate: float = 20.0) -> tuple[SyntheticRun, float]:
    """A synthetic run of about ``messages`` bag messages for the benchmarks: the cube's five
    poses visited in cycles under the three compensation modes, a move every
    :data:`LONG_RUN_PERIOD` s, the tracker at ``rate`` Hz; and the /legs/joint_states rate
    (Hz) that makes them :data:`JOINT_STATE_SHARE` of the bag (write_run_bag's
    ``joint_state_rate``)."""
    analysed_rate = 2 * rate + 2.0 / LONG_RUN_PERIOD  # measurement, truth, program, diagnostics
    filler_rate = analysed_rate * JOINT_STATE_SHARE / (1.0 - JOINT_STATE_SHARE)
    duration = messages / (analysed_rate + filler_rate) * 1.01
    cycles = max(2, int(np.ceil(duration / LONG_RUN_PERIOD / 3 / len(CUBE_POSITIONS))))
    run = synthetic_run(CUBE_POSITIONS, np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)), cycles=cycles,
                        rate=rate, move_time=1.0, dwell_time=LONG_RUN_PERIOD - 1.0, start=start,
                        seed=seed)
    return run, filler_rate
