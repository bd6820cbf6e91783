"""``calibrate_cell``: calibrate the running cell, or a recorded calibration run.

Live (default): on the cell of ``ROS_DOMAIN_ID``, the positioner is homed and set to mode
``none``; the measurement program (``positioning_cell.calibration.program``: D-optimal poses
and hold-out poses) is driven through ``/positioner/move_to_pose``; at each pose, once the move
is done, a marker goes out on ``/cell/calibration`` and the tool waits for ``--samples`` tracker
readings; a line per pose says how far the measured pose is from the commanded one and, every
ten poses, the residual of a fit so far. Then the machine is identified
(``positioning_cell.calibration.identify``), validated on the hold-out poses, and
``OUT/calibration.yaml`` and ``OUT/calibration_report.md`` (with plots) are written; the
positioner's mode is put back. ``--load`` also sets the positioner's
``compensation.calibration_file`` to the new file. Ctrl-C / SIGTERM stops the move
(``/positioner/stop``), puts the mode back and writes nothing.

From another thread (the ``calibrator`` node's Calibrate action): :func:`calibrate_live` with
a ``progress`` callback per measured pose and a ``stop`` event (the move is stopped at once,
the run ends as on Ctrl-C) gives the :class:`Outcome` with the identification's figures.

``--from-bag BAG``: the same identification from a recording of such a run (the markers, the
encoder readings and the tracker poses: :mod:`positioning_cell.calibration.collect`), the same
result from the same data.

Exit status: 0 written; 1 the data could not identify the machine (nothing written); 2 the cell
or the bag could not be used; 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.bag.opening import open_bag
from positioning_cell.calibration import collect as col
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.report import predict, write_report
from positioning_cell.config import config_path
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import CALIBRATION_FILE, PositionerSettings, machine_settings
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.messages import joint_values, measurement, seconds
from positioning_cell.ros.qos import MARKER_QOS, SERVICE_QOS, STREAM_QOS

EXIT_OK, EXIT_NOT_IDENTIFIED, EXIT_UNUSABLE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: The encoders' resolution as a standard uncertainty (1 µm and 2^20 counts per turn, /√12).
JOINT_SIGMA_FLOOR = np.r_[[1e-6 / np.sqrt(12)] * 3, [2 * np.pi / 2**20 / np.sqrt(12)] * 3]
#: For the estimate of the program's cell time: the tracker's reading rate (Hz).
TRACKER_RATE_HZ = 20.0
#: Progress: a fit so far every this many poses.
FIT_EVERY = 10


#: A measured pose, for a progress display: (pose k from 1, poses in the program, 'fit' or
#: 'hold_out', |measured - commanded| m).
Progress = Callable[[int, int, str, float], None]


class InterruptedRunError(Exception):
    """SIGINT or SIGTERM, or a stop asked from another thread (:func:`calibrate_live`)."""


class Figures(NamedTuple):
    """An identification in numbers: the fit poses' position residual RMS under the calibrated
    model (m), measured vs predicted at the hold-out poses (RMS, m; NaN without hold-out
    poses), and how many of how many parameters were identified."""

    fit_rms: float
    hold_out_rms: float
    identified: int
    parameters: int


class Outcome(NamedTuple):
    """How a calibration ended: the exit status, the calibration file (None: nothing written),
    the identification's figures (None: not identified), what happened in a few words, and
    whether the positioner loaded the file (None: not asked to)."""

    status: int
    path: Path | None = None
    figures: Figures | None = None
    reason: str = ''
    loaded: bool | None = None


class Machine(NamedTuple):
    """What the tool knows of the machine: the positioner's settings (nominal mechanism,
    payload, structure, motion limits, settle time)."""

    settings: PositionerSettings

    @classmethod
    def from_config(cls, config: Path) -> Machine:
        """The machine of the positioner's section of a parameter file."""
        return cls(machine_settings(config))


# -- the messages a run consists of -------------------------------------------------------------
class Recording:
    """Markers, encoder readings and tracker poses, as received (live) or read (bag)."""

    def __init__(self) -> None:
        # One entry per message (stamp and values together): a reader on another thread
        # never sees a stamp without its values.
        self.markers: list[col.Marker] = []
        self.joints: list[tuple[float, Any]] = []
        self.poses: list[tuple[float, Any, Any, Any]] = []

    def on_joints(self, msg: Any) -> None:
        values = joint_values(msg, JOINT_NAMES)
        if values is not None:
            self.joints.append((seconds(msg.header.stamp), values))

    def on_pose(self, msg: Any) -> None:
        reading = measurement(msg)
        self.poses.append((seconds(msg.header.stamp), reading.position, reading.quaternion,
                           reading.covariance))

    def on_marker(self, msg: Any) -> None:
        self.markers.append(col.Marker.from_json(msg.data))

    def readings_since(self, start: float) -> int:
        """Tracker readings stamped at or after ``start`` so far."""
        return sum(1 for entry in self.poses[-200:] if entry[0] >= start)

    def collected(self) -> col.Collected:
        joints, poses = list(self.joints), list(self.poses)  # what has come in so far
        jt, jv = zip(*joints, strict=True) if joints else ((), ())
        pt, p, q, c = zip(*poses, strict=True) if poses else ((), (), (), ())
        return col.collect(
            list(self.markers),
            col.Stream(np.asarray(jt, dtype=float), (np.asarray(jv).reshape(-1, 6),)),
            col.Stream(np.asarray(pt, dtype=float),
                       (np.asarray(p).reshape(-1, 3), np.asarray(q).reshape(-1, 4),
                        np.asarray(c).reshape(-1, 6, 6))),
            JOINT_SIGMA_FLOOR)


def read_bag(path: Path, run: str | None = None,
             say: Callable[[str], None] = print) -> Recording:
    """Calibration run ``run`` (default: the last one) recorded in the bag at ``path``
    (PositioningError if it lacks the markers, the encoder readings or the tracker poses)."""
    rec = Recording()
    handlers = {names.CALIBRATION: rec.on_marker, names.JOINT_STATES: rec.on_joints,
                names.MEASURED_POSE: rec.on_pose}
    with open_bag(path) as reader:
        missing = [t for t in handlers if t not in reader.topics]
        if missing:
            raise PositioningError(f'{path}: not a calibration run: no {", ".join(missing)}')
        for item in reader.messages(list(handlers)):
            handlers[item.topic](item.message)
    found = col.runs(rec.markers)
    if not found:
        raise PositioningError(f'{path}: no calibration marker on {names.CALIBRATION}')
    if run is None:
        run = found[-1]
    elif run not in found:
        raise PositioningError(f'{path}: no calibration run {run!r}; it holds '
                               f'{", ".join(found)}')
    rec.markers = [m for m in rec.markers if m.run == run]
    say(f'{path}: calibration run {run} ({len(rec.markers)} poses; runs in the bag: '
        f'{", ".join(found)})')
    return rec


# -- identification and output ------------------------------------------------------------------
def identify_and_write(machine: Machine, recording: Recording, out: Path, program: dict[str, Any],
                       say: Callable[[str], None]) -> Outcome:
    """Identify from the recording, validate on its hold-out poses, write the file and the
    report into ``out``: the :class:`Outcome` (exit status, the calibration file or None, the
    figures)."""
    s = machine.settings
    collected = recording.collected()
    for marker, why in collected.skipped:
        say(f'left out pose {marker.pose} ({marker.set}): {why}')
    try:
        result = idf.identify(s.mechanism, s.payload, s.structure, collected.fit)
    except idf.IdentificationError as err:
        say(f'calibrate_cell: not identified, nothing written: {err}')
        return Outcome(EXIT_NOT_IDENTIFIED, reason=f'not identified, nothing written: {err}')
    model = result.model(s.mechanism, s.payload, s.structure)
    fit = predict(s.mechanism, model, collected.fit)
    hold = predict(s.mechanism, model, collected.hold_out) if len(collected.hold_out.joints) \
        else None
    hold_doc = None
    if hold is not None:
        promised = idf.pose_uncertainty(result.x, result.covariance, s.mechanism, s.payload,
                                        s.structure, *collected.hold_out_commanded)
        sigma_p = np.sqrt(np.trace(promised[:, :3, :3], axis1=1, axis2=2))
        hold_doc = {'poses': len(collected.hold_out.joints),
                    'promised_sigma_um': round(float(np.sqrt(np.mean(sigma_p**2))) * 1e6, 3),
                    'nominal_rms_um': round(_rms(hold.nominal[0]) * 1e6, 3),
                    'calibrated_rms_um': round(_rms(hold.calibrated[0]) * 1e6, 3),
                    'calibrated_max_um': round(float(np.linalg.norm(hold.calibrated[0], axis=1)
                                                     .max()) * 1e6, 3)}
    out.mkdir(parents=True, exist_ok=True)
    doc = calfile.document(result, s.mechanism, idf.IdentificationSettings().seating_force,
                           program, hold_doc)
    path = calfile.write(out / 'calibration.yaml', doc)
    report = write_report(out, result, fit, hold)
    ident = result.identifiability
    say(f'identified {ident.rank}/{len(ident.identified)} parameters from '
        f'{len(collected.fit.joints)} poses (chi2/dof {result.chi2 / result.dof:.2f}); fit '
        f'residual RMS {_rms(fit.calibrated[0]) * 1e6:.2f} um (nominal model '
        f'{_rms(fit.nominal[0]) * 1e6:.1f} um)')
    if hold_doc is not None:
        say(f'hold-out ({hold_doc["poses"]} poses): measured vs predicted RMS '
            f'{hold_doc["calibrated_rms_um"]} um, max {hold_doc["calibrated_max_um"]} um '
            f'(nominal model {hold_doc["nominal_rms_um"]} um); the calibrated model\'s own '
            f'uncertainty there: {hold_doc["promised_sigma_um"]} um (1 sigma, |dp|)')
    if ident.merged:
        say('fixed (not separable): ' + ', '.join(ident.merged))
    say(f'calibration: {path}\nreport:      {report}')
    figures = Figures(_rms(fit.calibrated[0]),
                      _rms(hold.calibrated[0]) if hold is not None else float('nan'),
                      ident.rank, len(ident.identified))
    return Outcome(EXIT_OK, path, figures,
                   f'identified {ident.rank}/{len(ident.identified)} parameters from '
                   f'{len(collected.fit.joints)} poses, written to {path}')


def _rms(a: Any) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(a)**2, axis=1)))) if len(a) else float('nan')


# -- live ---------------------------------------------------------------------------------------
def _enough(rec: Recording, start: float, samples: int) -> bool:
    return rec.readings_since(start) >= samples


class _Stop:
    """A stop asked from another thread through ``event`` (None: only signals stop the run):
    :meth:`check` raises InterruptedRunError once it is set, :meth:`wait` is a
    :func:`wait_until` that also ends on it, and a watcher calls /positioner/stop as soon as it
    is set, so that the move running then ends at once."""

    def __init__(self, client: CellClient, event: threading.Event | None) -> None:
        self.event = event
        self._done = threading.Event()
        self._watcher: threading.Thread | None = None
        if event is not None:
            self._stop = client.node.create_client(Trigger, names.STOP, qos_profile=SERVICE_QOS)
            self._watcher = threading.Thread(target=self._watch, daemon=True)
            self._watcher.start()

    def _watch(self) -> None:
        assert self.event is not None
        while not self._done.is_set():
            if self.event.wait(0.05):
                if self._stop.service_is_ready():
                    self._stop.call_async(Trigger.Request())
                return

    def check(self) -> None:
        if self.event is not None and self.event.is_set():
            raise InterruptedRunError('stop requested')

    def wait(self, condition: Callable[[], Any], timeout: float, what: str) -> Any:
        if self.event is None:
            return wait_until(condition, timeout, what)
        event = self.event
        value = wait_until(lambda: event.is_set() or condition(), timeout, what)
        self.check()
        return value

    def close(self) -> None:
        self._done.set()
        if self._watcher is not None:
            self._watcher.join(timeout=1.0)


def _planning_covariance(recording: Recording, samples: int, timeout: float,
                         stop: _Stop) -> Any:
    """The tracker's covariance of one averaged pose, from its own readings at rest."""
    start = time.time()
    stop.wait(lambda: recording.readings_since(start) >= 1, timeout, 'a tracker reading')
    return np.asarray(recording.poses[-1][3]) / samples


def _progress_fit(machine: Machine, rec: Recording) -> str:
    """' ; fit so far ...': the residual of an identification on the poses measured so far."""
    s = machine.settings
    data = rec.collected().fit
    try:
        result = idf.identify(s.mechanism, s.payload, s.structure, data)
    except idf.IdentificationError as err:
        return f'; fit so far: not yet ({str(err).split(";")[0]})'
    return (f'; fit so far ({len(data.joints)} poses, {result.identifiability.rank} '
            f'parameters): residual RMS {_rms(result.pose_residual_position[:, None]) * 1e6:.2f}'
            ' um')


def run_live(client: CellClient, machine: Machine, settings: prog.ProgramSettings, samples: int,
             out: Path, say: Callable[[str], None], *, load: bool = False,
             timeout: float = 10.0, progress: Progress | None = None,
             stop: threading.Event | None = None) -> tuple[int, Path | None]:
    """The live calibration (module docstring): (exit status, the calibration file or None);
    :func:`calibrate_live` gives the whole :class:`Outcome`. :class:`InterruptedRunError`
    propagates after the drives were stopped and the mode put back."""
    outcome = calibrate_live(client, machine, settings, samples, out, say, load=load,
                             timeout=timeout, progress=progress, stop=stop)
    return outcome.status, outcome.path


def calibrate_live(client: CellClient, machine: Machine, settings: prog.ProgramSettings,
                   samples: int, out: Path, say: Callable[[str], None], *, load: bool = False,
                   timeout: float = 10.0, progress: Progress | None = None,
                   stop: threading.Event | None = None) -> Outcome:
    """The live calibration (module docstring) through ``client``, a line per pose to ``say``
    and, if given, ``progress(k, poses, set, |measured - commanded|)`` per measured pose.
    Setting ``stop`` (from another thread) stops the move at once (/positioner/stop) and ends
    the run as SIGINT does: :class:`InterruptedRunError` propagates after the drives were
    stopped and the mode put back, nothing written."""
    stopper = _Stop(client, stop)
    try:
        return _calibrate_live(client, machine, settings, samples, out, say, load, timeout,
                               progress, stopper)
    finally:
        stopper.close()


def _calibrate_live(client: CellClient, machine: Machine, settings: prog.ProgramSettings,
                    samples: int, out: Path, say: Callable[[str], None], load: bool,
                    timeout: float, progress: Progress | None, stop: _Stop) -> Outcome:
    rec = Recording()
    client.node.create_subscription(JointState, names.JOINT_STATES, rec.on_joints, STREAM_QOS)
    client.node.create_subscription(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                    rec.on_pose, STREAM_QOS)
    # Transient-local: a recorder that subscribes once it sees this publisher still gets every
    # marker sent before.
    markers = client.node.create_publisher(String, names.CALIBRATION, MARKER_QOS)
    s = machine.settings
    done, message = client.home()
    stop.check()  # a stop while homing ends the homing move (nothing else to undo yet)
    if not done:
        say(f'calibrate_cell: homing failed: {message}')
        return Outcome(EXIT_UNUSABLE, reason=f'homing failed: {message}')
    previous = str(client.get_parameter(names.NODE_POSITIONER, 'compensation.mode'))
    result = client.set_parameter(names.NODE_POSITIONER, 'compensation.mode', 'none')
    if not result.successful:
        say(f'calibrate_cell: the positioner refused mode none: {result.reason}')
        return Outcome(EXIT_UNUSABLE, reason=f'the positioner refused mode none: '
                       f'{result.reason}')
    run = datetime.datetime.now(datetime.UTC).isoformat(timespec='milliseconds')
    try:
        cov = _planning_covariance(rec, samples, timeout, stop)
        program = prog.choose(s.mechanism, s.payload, s.structure, settings, cov,
                              2 * JOINT_SIGMA_FLOOR)
        plan = [(col.FIT, p, q) for p, q in zip(program.position, program.quaternion,
                                                  strict=True)]
        plan += [(col.HOLD_OUT, p, q) for p, q in zip(program.hold_out_position,
                                                        program.hold_out_quaternion, strict=True)]
        estimate = prog.duration(s.mechanism, np.asarray([x[1] for x in plan]),
                                 np.asarray([x[2] for x in plan]), s.motion,
                                 s.settle_time + samples / TRACKER_RATE_HZ, settings.approach,
                                 s.settle_time)
        say(f'calibration program: {len(program.position)} poses + '
            f'{len(program.hold_out_position)} hold-out, about {estimate:.0f} s of cell time')
        for k, (which, p, q) in enumerate(plan, start=1):
            stop.check()
            head = f'[{k}/{len(plan)}] {which:<8}'
            # every pose approached the same way: from `approach` m below it along base z
            if settings.approach > 0.0:
                approached = client.plan(names.MOVE_TO_POSE,
                                         prog.approach_pose(p, settings.approach), q)
                stop.check()
                if not approached:
                    say(f'{head} approach pose refused or aborted: left out')
                    continue
            moved = client.plan(names.MOVE_TO_POSE, p, q)
            stop.check()
            if not moved:
                say(f'{head} move refused or aborted: left out')
                continue
            start = client.node.get_clock().now().nanoseconds * 1e-9
            marker = col.Marker(run, k - 1, which, (float(p[0]), float(p[1]), float(p[2])),
                                (float(q[0]), float(q[1]), float(q[2]), float(q[3])), start,
                                samples)
            markers.publish(String(data=marker.to_json()))
            rec.markers.append(marker)
            try:
                stop.wait(partial(_enough, rec, start, samples), timeout,
                          f'{samples} tracker readings')
            except TimeoutError as err:
                say(f'{head} {err}: left out')
                continue
            measured = np.mean([m[1] for m in rec.poses[-samples:]], axis=0)
            deviation = float(np.linalg.norm(measured - p))
            line = f'{head} |measured - commanded| {deviation * 1e6:7.1f} um'
            fits = sum(1 for m in rec.markers if m.set == col.FIT)
            if which == col.FIT and fits % FIT_EVERY == 0:
                line += _progress_fit(machine, rec)
            say(line)
            if progress is not None:
                progress(k, len(plan), which, deviation)
    except InterruptedRunError:
        client.trigger(names.STOP)
        with contextlib.suppress(TimeoutError):  # the interrupted move has ended before we leave
            wait_until(client.answered, timeout, 'the interrupted move to end')
        say('calibrate_cell: interrupted: drives stopped, nothing written')
        raise
    finally:
        client.set_parameter(names.NODE_POSITIONER, 'compensation.mode', previous)
    say('the recorder took the markers (calibrate_cell --from-bag can repeat this)'
        if client.subscribed(names.CALIBRATION, names.NODE_RECORDER)
        else 'no recorder took the markers: this run cannot be repeated from a bag')
    outcome = identify_and_write(machine, rec, out, {
        'poses': settings.poses, 'hold_out': settings.hold_out, 'samples': samples,
        'seed': settings.seed, 'candidates': settings.candidates}, say)
    if outcome.status == EXIT_OK and load and outcome.path is not None:
        loaded = client.set_parameter(names.NODE_POSITIONER, CALIBRATION_FILE,
                                      str(outcome.path.resolve()))
        say('the positioner loaded it' if loaded.successful
            else f'the positioner refused it: {loaded.reason}')
        outcome = outcome._replace(loaded=loaded.successful, reason=outcome.reason + (
            '; the positioner loaded it' if loaded.successful
            else f'; the positioner refused it: {loaded.reason}'))
    return outcome


def say(text: str) -> None:
    """A progress line, at once."""
    print(text, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    defaults = prog.ProgramSettings()
    parser = argparse.ArgumentParser(prog='calibrate_cell', description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, default=Path('calibration'),
                        help='folder for calibration.yaml and the report (default ./calibration)')
    parser.add_argument('--from-bag', type=Path, help='identify from a recorded calibration run')
    parser.add_argument('--run', help='with --from-bag: which run (its start, as printed; '
                        'default: the last in the bag)')
    parser.add_argument('--config', type=Path, help='parameter file of the cell (default: the '
                        'shipped config/cell.yaml): the nominal machine and its payload')
    parser.add_argument('--poses', type=int, default=defaults.poses)
    parser.add_argument('--hold-out', type=int, default=defaults.hold_out)
    parser.add_argument('--samples', type=int, default=10,
                        help='tracker readings averaged per pose')
    parser.add_argument('--seed', type=int, default=defaults.seed, help='candidate draw')
    parser.add_argument('--approach', type=float, default=defaults.approach,
                        help='approach each pose from this far below it, m (0: directly)')
    parser.add_argument('--load', action='store_true',
                        help='set the positioner\'s compensation.calibration_file afterwards')
    args = parser.parse_args(argv)
    try:
        machine = Machine.from_config(args.config or config_path('cell.yaml'))
        settings = replace(defaults, poses=args.poses, hold_out=args.hold_out, seed=args.seed,
                           approach=args.approach)
    except PositioningError as err:
        say(f'calibrate_cell: error: {err}')
        return EXIT_UNUSABLE
    if args.from_bag is not None:
        try:
            recording = read_bag(args.from_bag, args.run, say)
        except PositioningError as err:
            say(f'calibrate_cell: error: {err}')
            return EXIT_UNUSABLE
        return identify_and_write(machine, recording, args.out, {'from_bag': str(args.from_bag)},
                                  say)[0]

    def on_signal(signum: int, frame: Any) -> None:
        raise InterruptedRunError(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    client = CellClient(name='calibrate_cell', signals=False)
    try:
        return run_live(client, machine, settings, args.samples, args.out, say,
                        load=args.load)[0]
    except InterruptedRunError:
        return EXIT_INTERRUPTED
    except TimeoutError as err:
        say(f'calibrate_cell: error: {err}')
        return EXIT_UNUSABLE
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        client.close()


if __name__ == '__main__':
    sys.exit(main())
