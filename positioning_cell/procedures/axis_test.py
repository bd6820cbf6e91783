"""The axis test on a running cell (ISO 230-2:2014 per actuator; the program:
:mod:`positioning_cell.analysis.axis_test`, ``config/axis_test.yaml``), through a
:class:`~positioning_cell.procedures.port.CellPort`: the live cell (``axis_test``, ``run_cell
--axis-test``) or the in-process one of the tests.

With the positioner in mode ``none`` (put back afterwards): home (the nominal home pose); the
home values of the six axes from the encoders at rest; per axis, per stop of its linear cycles,
the axis driven by the positioner's jog (a step longer than the largest jog step split), the
dwell, then ``samples`` tracker readings stamped from then on averaged (as the calibration
does), with the encoder readings and, simulated, the true axis positions over the same window;
the measured actuator value is the inverse kinematics of that averaged pose through the cell's
own machine model (the calibrated machine when the positioner has a calibration file loaded,
else the nominal one), the true one (judging only) the true axis position plus the truth's zero
offset (the simulator's ``truth.*`` of the parameter file, :mod:`.judging`). A marker per
measured stop goes out on ``/cell/axis_test`` (kept for a recorder that joins late) and a line
per stop to the caller. Each axis returns to its home value after its last cycle, and the
positioner homes at the end, so a run continues from home.
"""

from __future__ import annotations

import datetime
import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from positioning_cell import names
from positioning_cell.analysis.axis_test import (
    CALIBRATED,
    NOMINAL,
    UP,
    AxisTest,
    AxisTestMarker,
    AxisTestResults,
    actuator_uncertainty,
    actuator_values,
    axis_test_figures,
    is_linear,
)
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.motion.settings import CompensationMode, PositionerSettings, machine_settings
from positioning_cell.moves.correction import mean_reading
from positioning_cell.procedures.judging import simulation_truth
from positioning_cell.procedures.port import (
    CellPort,
    ProcedureError,
    Say,
    in_mode,
    moved_or_raise,
    say_recorded,
)

#: Per-call overhead of a jog on the live cell (service call, arrival detection), s: for the
#: estimate of the test's duration only.
JOG_OVERHEAD = 0.18
#: The tracker's reading rate (Hz), for the estimate of the duration.
TRACKER_RATE_HZ = 20.0
#: Result codes of a jog that a busy machine can cause and that leave the axes stopped and
#: able to go on (a moment's silence of the encoders, or of the tracker, which the positioner
#: watches in mode measured; a call while the last one finishes): the procedure tries again
#: from where the axis stands.
TRANSIENT = ('aborted_driver_lost', 'refused_driver_silent', 'aborted_tracker_lost',
             'refused_tracker_silent', 'refused_busy')
#: How often one move is tried again after a transient abort, and the rest before each try, s.
RETRIES, RETRY_REST = 3, 0.5


class ModeRefusedError(ProcedureError):
    """The positioner refused mode ``none``: the test did not start, nothing moved."""


class Reference(NamedTuple):
    """The machine model that turns a measured pose into actuator values, and its name
    (calibrated or nominal)."""

    model: MachineModel
    name: str


class AxisTestRun(NamedTuple):
    """A completed axis test: the markers of its measured stops (as sent) and their ISO 230-2
    figures."""

    markers: list[AxisTestMarker]
    results: AxisTestResults


def reference_machine(port: CellPort, settings: PositionerSettings) -> Reference:
    """The positioner's own machine model: the calibration file it has loaded
    (``compensation.calibration_file``), else the nominal machine of ``settings``."""
    path = port.calibration_file()
    if not path:
        return Reference(MachineModel(settings.mechanism), NOMINAL)
    model = calfile.load(path, settings.mechanism).model(settings.mechanism, settings.payload,
                                                         settings.structure)
    return Reference(model, CALIBRATED)


def _jog_to(port: CellPort, axis: str, goal: float, largest: float) -> None:
    """Jog ``axis`` to ``goal`` (absolute, m or rad) in as few equal steps within ``largest``
    as it takes, each from where the encoders stand (ProcedureError, with the positioner's
    code, when a jog is refused or aborted)."""
    k = JOINT_NAMES.index(axis)
    pieces = max(1, math.ceil(abs(goal - float(port.joints()[k])) / largest - 1e-9))
    for left in range(pieces, 0, -1):
        delta = (goal - float(port.joints()[k])) / left
        moved_or_raise(port.jog(axis, delta), f'jog {axis} by {delta:+.7g}')


def _move(port: CellPort, axis: str, goal: float, largest: float, back_off: float,
          say: Say) -> None:
    """:func:`_jog_to`, tried again up to :data:`RETRIES` times after a transient abort
    (:data:`TRANSIENT`): from where the axis stopped, or, if it stopped beyond ``goal``, from
    ``back_off`` short of it, so that ``goal`` is still approached in its direction."""
    k = JOINT_NAMES.index(axis)
    direction = math.copysign(1.0, goal - float(port.joints()[k]))
    for attempt in range(RETRIES + 1):
        try:
            if attempt and (goal - float(port.joints()[k])) * direction < 0.0:
                _jog_to(port, axis, goal - direction * back_off, largest)
            _jog_to(port, axis, goal, largest)
            return
        except ProcedureError as err:
            if err.code not in TRANSIENT or attempt == RETRIES:
                raise
            say(f'{axis}: {err}; trying again ({attempt + 1}/{RETRIES})')
            port.rest(RETRY_REST)


def _amount(axis: str, value: float) -> str:
    return (f'{value * 1e6:+8.2f} µm' if is_linear(axis) else f'{value * 1e6:+8.1f} µrad')


def run_procedure(port: CellPort, test: AxisTest, reference: Reference,
                  largest_steps: tuple[float, float], say: Say, *,
                  truth: MachineModel | None = None, run: str | None = None,
                  timeout: float = 30.0) -> list[AxisTestMarker]:
    """The axis test (module docstring) through ``port``, in the mode the positioner is in:
    the markers of its measured stops, each also sent on ``/cell/axis_test``.
    ``largest_steps``: the largest jog step of a leg (m) and of a θ axis (rad); ``truth``
    (simulation, judging only): the true machine whose zero offsets turn the true axis
    positions into true actuator values; ``timeout`` s for the readings of a stop.
    ProcedureError propagates (the positioner is asked to home first when the error was not
    the homing itself)."""
    run = run or datetime.datetime.now(datetime.UTC).isoformat(timespec='milliseconds')
    offsets = (None if truth is None
               else np.concatenate([truth.length_offsets, truth.theta_offsets]))
    moved_or_raise(port.home(), 'homing')
    port.rest(test.dwell)
    home = port.readings(test.samples, timeout).encoder
    markers: list[AxisTestMarker] = []
    total, width = test.measured_stops, len(str(test.measured_stops))
    begin = port.now()
    try:
        for plan in test.axes:
            k = JOINT_NAMES.index(plan.axis)
            largest = largest_steps[0] if is_linear(plan.axis) else largest_steps[1]
            for stop in test.stops(plan.axis):
                goal = float(home[k] + stop.position)
                _move(port, plan.axis, goal, largest, plan.overshoot, say)
                if not stop.measured or stop.index is None:
                    continue
                port.rest(test.dwell)
                r = port.readings(test.samples, timeout)
                p, q, cov = mean_reading(
                    r.position, r.quaternion, r.covariance, None if r.registration is None
                    else r.registration.covariance_at(r.position.mean(axis=0))[0])
                tracker = float(actuator_values(reference.model, p, q)[k])
                tracker_u = float(actuator_uncertainty(reference.model, p, q, cov)[k])
                true = (None if r.true is None or offsets is None
                        else float(r.true[k] + offsets[k]))
                marker = AxisTestMarker(run, plan.axis, stop.index, plan.targets[stop.index],
                                        stop.direction, stop.cycle, goal, float(r.encoder[k]),
                                        tracker, true, r.start, r.end, len(r.position),
                                        reference.name,
                                        tracker_u if math.isfinite(tracker_u) else None)
                port.mark(names.AXIS_TEST, marker.to_json())
                markers.append(marker)
                arrow = '↑' if stop.direction == UP else '↓'
                truth_text = ('' if true is None
                              else f', truth x {_amount(plan.axis, true - goal)}')
                say(f'[{len(markers):>{width}}/{total}] {plan.axis:<11} cycle {stop.cycle} '
                    f'{arrow} P{stop.index + 1} {stop.position * 1e3:+.4f} '
                    f'{"mm" if is_linear(plan.axis) else "mrad"}: tracker x '
                    f'{_amount(plan.axis, tracker - goal)}{truth_text} '
                    f'[{port.now() - begin:.0f} s]')
    except ProcedureError:
        port.home()  # so that a run continues from home; the error says what went wrong
        raise
    moved_or_raise(port.home(), 'homing')
    return markers


def run_axis_test(port: CellPort, test: AxisTest, config: Path, say: Say, *,
                  judge: bool = True, timeout: float = 30.0) -> AxisTestRun:
    """The axis test on the cell of ``port`` with the positioner's machine of ``config`` (its
    jog steps and speeds; its calibration when the positioner has one loaded) and, with
    ``judge``, the simulator's truth of ``config``: in mode ``none``, put back afterwards
    (ModeRefusedError when the positioner refuses it). The drives are stopped when anything
    but a refusal or an abort of the cell (an interrupt, say) ends it."""
    settings = machine_settings(config)
    op = settings.operator
    reference = reference_machine(port, settings)
    truth = simulation_truth(config) if judge else None
    estimate = test.duration(op.jog_length_speed, op.jog_length_acceleration, op.jog_theta_speed,
                             op.jog_theta_acceleration, settings.settle_time, TRACKER_RATE_HZ,
                             JOG_OVERHEAD)
    axes = f'{len(test.axes)} {"axis" if len(test.axes) == 1 else "axes"}'
    say(f'axis test (ISO 230-2): {axes}, {test.measured_stops} measured stops '
        f'({test.cycles} cycles), {test.samples} tracker readings each; actual positions from '
        f'the tracker through the {reference.name} machine'
        + (' and from the simulation truth' if truth is not None else '')
        + f'; about {estimate / 60:.1f} min')
    # Mode none while it runs, as the calibration measures: the home pose is the nominal
    # machine's (the home values the program was checked at) and a jog, outside the
    # kinematics anyway, does not depend on the tracker's liveness.
    with in_mode(port, CompensationMode.NONE.value, 'axis test', say, ModeRefusedError):
        markers = run_procedure(port, test, reference,
                                (op.jog_largest_length_step, op.jog_largest_theta_step), say,
                                truth=truth, timeout=timeout)
    say_recorded(port, names.AXIS_TEST, say)
    return AxisTestRun(markers, axis_test_figures(markers))


def write(results: AxisTestResults, out: Path) -> tuple[Path, Path]:
    """``axis_test.md`` (the tables) and ``axis_test.json`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    md, js = out / 'axis_test.md', out / 'axis_test.json'
    md.write_text('# Axis test (ISO 230-2:2014)\n\n' + '\n'.join(results.markdown()) + '\n')
    js.write_text(json.dumps(results.to_dict(), indent=1))
    return md, js

