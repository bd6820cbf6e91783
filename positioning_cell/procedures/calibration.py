"""The live calibration of the cell, on any :class:`~positioning_cell.procedures.port.CellPort`
(the running cell: ``calibrate_cell``, the ``calibrator`` node's Calibrate action,
``run_cell``; in process: the tests).

:func:`calibrate`: the positioner is homed and set to compensation mode ``none`` (its mode is
put back afterwards, whatever happens); the covariance of an averaged tracker pose is taken
from the tracker's own reading at rest; the measurement program
(:func:`positioning_cell.calibration.program.choose`: poses chosen by the D, I or G criterion,
and hold-out poses; its criterion, predicted pose σ at the production poses and observability
indices said) is driven pose by pose, each approached through a pose ``approach`` m from it
along base z (``approach_rule``: below every pose, or below and above in turn:
:func:`~positioning_cell.calibration.program.approach_poses`), then the pose; at each pose
``samples`` tracker readings are taken with the encoder values over the same window, the pose's
conditions (the air-temperature sensor's reading and the side each axis came from:
:func:`~positioning_cell.calibration.collect.pose_conditions`, what the port holds of the
encoder and temperature streams) are taken with them, and a marker
(:class:`~positioning_cell.calibration.collect.Marker`, with the window's start) goes out on
``/cell/calibration`` so that a recorder keeps what ``calibrate_cell --from-bag`` needs to
repeat the identification from the same data. A pose the cell refuses, aborts or does not
measure in time is left out (said). A line per pose says how far the measured pose is from the
commanded one and, every ten fit poses, the residual of a fit so far. Then the machine is
identified from what the port measured (never the simulator's truth), validated on the hold-out
poses, and ``OUT/calibration.yaml`` and ``OUT/calibration_report.md`` are written
(:mod:`positioning_cell.calibration.identified`); ``load`` then asks the positioner to load the
file.

A stop (``stop``, an event set from another thread: an action's cancel, a node's shutdown)
stops the drives at once, puts the mode back, writes nothing and raises
:class:`~positioning_cell.procedures.stopping.Stopped`; any other exception raised in the
program (a signal's, in a command line) stops the drives and puts the mode back the same
way before it propagates.
"""

from __future__ import annotations

import datetime
import threading
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from positioning_cell import names
from positioning_cell.calibration import collect as col
from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.identified import Figures, fit_so_far, identify_and_write
from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.motion.settings import CompensationMode, PositionerSettings
from positioning_cell.procedures.port import CellPort, Moved, ProcedureError, Say
from positioning_cell.procedures.stopping import Stopped, StopSignal

#: For the estimate of the program's cell time: the tracker's reading rate (Hz).
TRACKER_RATE_HZ = 20.0
#: Progress: a fit so far every this many fit poses.
FIT_EVERY = 10

#: A measured pose, for a progress display: (pose k from 1, poses in the program, 'fit' or
#: 'hold_out', |measured - commanded| m).
Progress = Callable[[int, int, str, float], None]


class Status(Enum):
    """How a calibration ended (a command line maps it to its exit code)."""

    WRITTEN = 'written'                # identified, the file written
    NOT_IDENTIFIED = 'not_identified'  # measured, but the data did not identify the machine
    REFUSED = 'refused'                # the cell refused a step (homing, mode none)
    ABORTED = 'aborted'                # a step the cell could not complete (homing)
    NOT_THERE = 'not_there'            # an answer or a reading did not come in time


class Outcome(NamedTuple):
    """How a calibration ended: its status, the calibration file (None: nothing written), the
    identification's figures (None: not identified), what happened in a few words, and whether
    the positioner loaded the file (None: not asked to)."""

    status: Status
    path: Path | None = None
    figures: Figures | None = None
    reason: str = ''
    loaded: bool | None = None

    @property
    def succeeded(self) -> bool:
        """Written, and loaded when that was asked."""
        return self.status is Status.WRITTEN and self.loaded is not False


def _failed(moved: Moved) -> Status:
    """The status of a step that did not succeed, by the positioner's result code."""
    if not moved.code:
        return Status.NOT_THERE
    return Status.REFUSED if moved.code.startswith('refused') else Status.ABORTED


def calibrate(port: CellPort, machine: PositionerSettings, program: ProgramSettings,
              samples: int, out: Path, say: Say, *, stop: threading.Event | None = None,
              load: bool = False, timeout: float = 10.0,
              progress: Progress | None = None) -> Outcome:
    """The live calibration (module docstring) of the cell behind ``port``: the nominal
    machine ``machine`` (its mechanism, payload, structure, motion limits and settle time),
    the program ``program``, ``samples`` tracker readings averaged per pose (``timeout`` s
    for them), the file and the report into ``out``; a line per pose to ``say`` and, if given,
    ``progress(k, poses, set, |measured - commanded| m)`` per measured pose. Setting ``stop``
    ends it as the module docstring says (:class:`Stopped` raised)."""
    with StopSignal(stop, port.stop) as signal:
        try:
            return _calibrate(port, machine, program, samples, out, say, load, timeout,
                              progress, signal)
        except Stopped:
            say('calibration stopped: drives stopped, nothing written')
            raise


def _calibrate(port: CellPort, machine: PositionerSettings, program: ProgramSettings,
               samples: int, out: Path, say: Say, load: bool, timeout: float,
               progress: Progress | None, signal: StopSignal) -> Outcome:
    began = port.now()  # the first pose's look-back for its approach: from the homing on
    moved = port.home()
    signal.check()  # a stop while homing ends the homing move (nothing else to undo yet)
    if not moved.success:
        return _ended(say, _failed(moved), f'homing failed: {moved.code or "no answer"}: '
                      f'{moved.reason}')
    try:
        previous = port.mode()
    except ProcedureError as err:
        return _ended(say, Status.NOT_THERE, str(err))
    try:
        port.set_mode(CompensationMode.NONE.value)
    except ProcedureError as err:
        return _ended(say, Status.REFUSED, str(err))
    try:
        measured = _measure(port, machine, program, samples, say, timeout, progress, signal,
                            began)
    except ProcedureError as err:  # the tracker gave no reading: nothing measured
        return _ended(say, Status.NOT_THERE, str(err) + _put_back(port, previous, say))
    except BaseException:
        port.stop()  # a stop, a signal, an error: the drives first, then the mode
        _put_back(port, previous, say)
        raise
    restored = _put_back(port, previous, say)
    say('the recorder took the markers (calibrate_cell --from-bag can repeat this)'
        if port.recorded(names.CALIBRATION)
        else 'no recorder took the markers: this run cannot be repeated from a bag')
    doc = {'poses': program.poses, 'hold_out': program.hold_out, 'samples': samples,
           'seed': program.seed, 'candidates': program.candidates,
           'criterion': program.criterion, 'production': program.production,
           'approach': program.approach, 'approach_rule': program.approach_rule}
    collected = col.assemble(measured)
    for why in collected.missing:
        say(f'calibration: the poses carry no {why}')
    try:
        written = identify_and_write(machine, collected, out, doc, say)
    except idf.IdentificationError as err:
        return _ended(say, Status.NOT_IDENTIFIED, f'not identified, nothing written: {err}'
                      + restored)
    outcome = Outcome(Status.WRITTEN, written.path, written.figures, written.summary + restored)
    if load:
        taken, why = port.load_calibration(str(written.path.resolve()))
        words = 'the positioner loaded it' if taken else f'the positioner refused it: {why}'
        say(words)
        outcome = outcome._replace(loaded=taken, reason=f'{outcome.reason}; {words}')
    return outcome


def _ended(say: Say, status: Status, reason: str) -> Outcome:
    say(f'calibration: {reason}')
    return Outcome(status, reason=reason)


def _put_back(port: CellPort, mode: str, say: Say) -> str:
    """Put the compensation mode back: '' or, when the positioner did not take it, a clause
    for the outcome's reason (said too)."""
    try:
        port.set_mode(mode)
    except ProcedureError as err:
        say(f'calibration: the mode was not put back: {err}')
        return f'; the mode was not put back ({err})'
    return ''


def _measure(port: CellPort, machine: PositionerSettings, program: ProgramSettings,
             samples: int, say: Say, timeout: float, progress: Progress | None,
             signal: StopSignal, since: float) -> list[col.PoseData]:
    """Drive the program and measure each pose: the measured poses (ProcedureError when the
    tracker gives no reading at all); the first pose's approach from the encoder readings
    since ``since`` s."""
    s = machine
    # the tracker's covariance of one averaged pose, from its own reading at rest
    cov = port.readings(1, timeout).covariance[-1] / samples
    signal.check()
    chosen = prog.choose(s.mechanism, s.payload, s.structure, program, cov,
                         2 * col.JOINT_SIGMA_FLOOR)
    plan = [(col.FIT, p, q) for p, q in zip(chosen.position, chosen.quaternion, strict=True)]
    plan += [(col.HOLD_OUT, p, q) for p, q in zip(chosen.hold_out_position,
                                                    chosen.hold_out_quaternion, strict=True)]
    visited = np.asarray([x[1] for x in plan])
    estimate = prog.duration(s.mechanism, visited, np.asarray([x[2] for x in plan]), s.motion,
                             s.settle_time + samples / TRACKER_RATE_HZ, program.approach,
                             s.settle_time, program.approach_rule)
    vias = prog.approach_poses(visited, program.approach, program.approach_rule)
    say(f'calibration program: {len(chosen.position)} poses + '
        f'{len(chosen.hold_out_position)} hold-out, about {estimate:.0f} s of cell time; '
        + program_words(chosen))
    run = datetime.datetime.now(datetime.UTC).isoformat(timespec='milliseconds')
    measured: list[col.PoseData] = []
    for k, (which, p, q) in enumerate(plan, start=1):
        signal.check()
        head = f'[{k}/{len(plan)}] {which:<8}'
        prior = measured[-1].conditions if measured else None
        pose = _measure_pose(port, program.approach > 0.0, samples, timeout, signal, run,
                             k - 1, which, (p, q, vias[k - 1]),
                             (since, None if prior is None else prior.approach))
        if isinstance(pose, str):
            say(f'{head} {pose}: left out')
            continue
        since = pose.marker.start
        measured.append(pose)
        deviation = float(np.linalg.norm(pose.position - p))
        line = f'{head} |measured - commanded| {deviation * 1e6:7.1f} um'
        fits = sum(1 for m in measured if m.marker.set == col.FIT)
        if which == col.FIT and fits % FIT_EVERY == 0:
            line += fit_so_far(machine, col.assemble(measured))
        say(line)
        if progress is not None:
            progress(k, len(plan), which, deviation)
    return measured


def program_words(chosen: prog.Program) -> str:
    """What the program promises, in a few words: its criterion, the predicted pose σ at the
    production poses (equivalent position, RMS) and its observability indices."""
    words = f'chosen by criterion {chosen.criterion}'
    if chosen.production_sigma is not None:
        sigma = chosen.production_sigma
        words += (f', predicted sigma at the {len(sigma)} production poses '
                  f'{np.sqrt(np.mean(sigma**2)) * 1e6:.2f} um RMS')
    if chosen.indices is not None:
        ind = chosen.indices
        words += (f'; smallest singular value {ind.sigma_min:.3g}, condition '
                  f'{ind.condition:.3g}, O1 {ind.o1:.3g}')
    return words


def _measure_pose(port: CellPort, approach: bool, samples: int, timeout: float,
                  signal: StopSignal, run: str, index: int, which: str,
                  goal: tuple[Any, Any, Any], before: tuple[float, Any]) -> col.PoseData | str:
    """Approach (through ``goal``'s third, the approach position, if ``approach``), move to
    and measure one pose ``goal`` (position, quaternion): its data (conditions taken from the
    streams since ``before``'s start, its approach the prior) and marker sent, or why not."""
    p, q, via = goal
    if approach:
        moved = port.move(via, q)
        signal.check()
        if not moved.success:
            return f'approach pose {moved.code or "no answer"}: {moved.reason}'
    moved = port.move(p, q)
    signal.check()
    if not moved.success:
        return f'move {moved.code or "no answer"}: {moved.reason}'
    try:
        r = port.readings(samples, timeout)
    except ProcedureError as err:
        return str(err)
    signal.check()
    marker = col.Marker(run, index, which, (float(p[0]), float(p[1]), float(p[2])),
                        (float(q[0]), float(q[1]), float(q[2]), float(q[3])), r.start,
                        samples)
    port.mark(names.CALIBRATION, marker.to_json())
    sem = r.encoder_sem if r.encoder_sem is not None else np.zeros(6)
    enc_t, enc_v = port.encoder_stream(before[0])
    air_t, air_v = port.air_temperature(r.start - col.TEMPERATURE_AGE)
    conditions = col.pose_conditions(col.Stream(enc_t, (enc_v,)), col.Stream(air_t, (air_v,)),
                                     r.start, r.end, r.encoder, before[1])
    return col.pose_data(marker, r.encoder, sem, r.position, r.quaternion, r.covariance,
                         col.JOINT_SIGMA_FLOOR, conditions, r.registration)
