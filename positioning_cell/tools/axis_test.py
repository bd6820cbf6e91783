"""The axis test on the running cell (ISO 230-2:2014 per actuator; the program:
:mod:`positioning_cell.analysis.axis_test`, ``config/axis_test.yaml``). ``run_cell
--axis-test`` runs it after the calibration; on its own, on the cell of ``ROS_DOMAIN_ID``:

    python -m positioning_cell.tools.axis_test [--program F] [--config F] [--out DIR]

The procedure (:func:`run_procedure`, written against a :class:`Port`: the ROS one here,
:class:`CellPort`, or a simulated cell in the tests), with the positioner in mode ``none``
(put back afterwards): home (``/positioner/home``: the nominal home pose); the home
values of the six axes from the encoders at rest; per axis, per stop of its linear cycles, the
axis driven by the positioner's jog (``/positioner/jog``, a step longer than the largest jog
step split), the dwell, then ``samples`` tracker readings (``/metrology/pose``) stamped from
then on averaged (as ``calibrate_cell`` does), with the encoder readings and, in simulation,
the true axis positions (``/sim/legs/true_joint_states``) over the same window; the measured
actuator value is the inverse kinematics of that averaged pose through the cell's own machine
model (the calibrated machine when the positioner has a calibration file loaded, else the
nominal one), the true one (judging only) the true axis position plus the truth's zero offset
(the simulator's ``truth.*`` of the parameter file). A marker per measured stop goes out on
``/cell/axis_test`` (transient-local, so a recorder that joins late still gets them all) and a
line per stop to the caller. Each axis returns to its home value after its last cycle, and the
positioner homes at the end, so a run continues from home.

Exit status of the command: 0 done; 2 the program or the cell could not be used, or the test
was aborted; 130 interrupted (the drives are stopped).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from numpy.typing import NDArray
from positioning_cell_interfaces.srv import Jog
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from positioning_cell import names
from positioning_cell.analysis.axis_test import (
    CALIBRATED,
    NOMINAL,
    UP,
    AxisTest,
    AxisTestMarker,
    AxisTestResults,
    actuator_values,
    axis_test_figures,
    is_linear,
    load_axis_test,
)
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import CALIBRATION_FILE, PositionerSettings, machine_settings
from positioning_cell.moves.correction import mean_pose
from positioning_cell.parameters import parse
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.messages import joint_values, pose_arrays, seconds
from positioning_cell.ros.qos import MARKER_QOS, STREAM_QOS
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings

FloatArray = NDArray[np.float64]

EXIT_OK, EXIT_UNUSABLE, EXIT_INTERRUPTED = 0, 2, 130
#: Messages kept per stream (at 100 Hz, 30 s): a stop's window is far shorter.
HISTORY = 3000
#: Per-call overhead of a jog on the live cell (service call, arrival detection), s: for the
#: estimate of the test's duration only.
JOG_OVERHEAD = 0.18
#: The tracker's reading rate (Hz), for the estimate of the duration.
TRACKER_RATE_HZ = 20.0
#: The positioner's compensation mode parameter.
MODE = 'compensation.mode'


#: Result codes of a jog that a busy machine can cause and that leave the axes stopped and
#: able to go on (a moment's silence of the encoders, or of the tracker, which the positioner
#: watches in mode measured; a call while the last one finishes): the procedure tries again
#: from where the axis stands.
TRANSIENT = ('aborted_driver_lost', 'refused_driver_silent', 'aborted_tracker_lost',
             'refused_tracker_silent', 'refused_busy')
#: How often one move is tried again after a transient abort, and the rest before each try, s.
RETRIES, RETRY_REST = 3, 0.5


class AxisTestError(PositioningError):
    """The cell refused or did not complete a step of the axis test (the reason; ``code``:
    the positioner's result code when it gave one)."""

    def __init__(self, message: str, code: str = '') -> None:
        super().__init__(message)
        self.code = code


class Readings(NamedTuple):
    """What a measured stop reads: the tracker poses (k, 3) m and (k, 4) x, y, z, w in
    ``base``, the mean encoder values (6,) over their window, the mean true axis positions
    (6,) (encoder coordinate, simulation only; else None), and the window ``start`` …
    ``end`` (s)."""

    position: FloatArray
    quaternion: FloatArray
    encoder: FloatArray
    true: FloatArray | None
    start: float
    end: float


class Port(Protocol):
    """The cell as the procedure uses it."""

    def home(self) -> None:
        """Reference and home; AxisTestError if that fails."""

    def joints(self) -> FloatArray:
        """The latest encoder reading (6,), m and rad."""

    def jog(self, axis: str, delta: float) -> None:
        """Jog ``axis`` by ``delta`` (m or rad, within the largest jog step); returns at rest.
        AxisTestError if refused or aborted."""

    def rest(self, seconds: float) -> None:
        """Let ``seconds`` pass with the axes at rest."""

    def measure(self, samples: int) -> Readings:
        """The next ``samples`` tracker readings and the encoder (and true) values over them."""

    def publish(self, marker: AxisTestMarker) -> None:
        """Send a marker out."""


class Reference(NamedTuple):
    """The machine model that turns a measured pose into actuator values, and its name
    (calibrated or nominal)."""

    model: MachineModel
    name: str


def _jog_to(port: Port, axis: str, goal: float, largest: float) -> None:
    """Jog ``axis`` to ``goal`` (absolute, m or rad) in as few equal steps within ``largest``
    as it takes, each from where the encoders stand."""
    k = JOINT_NAMES.index(axis)
    pieces = max(1, math.ceil(abs(goal - float(port.joints()[k])) / largest - 1e-9))
    for left in range(pieces, 0, -1):
        port.jog(axis, (goal - float(port.joints()[k])) / left)


def _move(port: Port, axis: str, goal: float, largest: float, back_off: float,
          say: Callable[[str], None]) -> None:
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
        except AxisTestError as err:
            if err.code not in TRANSIENT or attempt == RETRIES:
                raise
            say(f'{axis}: {err}; trying again ({attempt + 1}/{RETRIES})')
            port.rest(RETRY_REST)


def _amount(axis: str, value: float) -> str:
    return (f'{value * 1e6:+8.2f} µm' if is_linear(axis) else f'{value * 1e6:+8.1f} µrad')


def run_procedure(port: Port, test: AxisTest, reference: Reference, largest_steps: tuple[
        float, float], say: Callable[[str], None], *, truth: MachineModel | None = None,
        run: str | None = None) -> list[AxisTestMarker]:
    """The axis test (module docstring) through ``port``: the markers of its measured stops,
    each also published. ``largest_steps``: the largest jog step of a leg (m) and of a θ axis
    (rad); ``truth`` (simulation, judging only): the true machine whose zero offsets turn the
    true axis positions into true actuator values. AxisTestError propagates (the positioner
    is asked to home first when the error was not the homing itself)."""
    run = run or datetime.datetime.now(datetime.UTC).isoformat(timespec='milliseconds')
    offsets = (None if truth is None
               else np.concatenate([truth.length_offsets, truth.theta_offsets]))
    port.home()
    port.rest(test.dwell)
    home = port.measure(test.samples).encoder
    markers: list[AxisTestMarker] = []
    total, width = test.measured_stops, len(str(test.measured_stops))
    begin = time.monotonic()
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
                r = port.measure(test.samples)
                p, q = mean_pose(r.position, r.quaternion)
                tracker = float(actuator_values(reference.model, p, q)[k])
                true = (None if r.true is None or offsets is None
                        else float(r.true[k] + offsets[k]))
                marker = AxisTestMarker(run, plan.axis, stop.index, plan.targets[stop.index],
                                        stop.direction, stop.cycle, goal, float(r.encoder[k]),
                                        tracker, true, r.start, r.end, len(r.position),
                                        reference.name)
                port.publish(marker)
                markers.append(marker)
                arrow = '↑' if stop.direction == UP else '↓'
                truth_text = ('' if true is None
                              else f', truth x {_amount(plan.axis, true - goal)}')
                say(f'[{len(markers):>{width}}/{total}] {plan.axis:<11} cycle {stop.cycle} '
                    f'{arrow} P{stop.index + 1} {stop.position * 1e3:+.4f} '
                    f'{"mm" if is_linear(plan.axis) else "mrad"}: tracker x '
                    f'{_amount(plan.axis, tracker - goal)}{truth_text} '
                    f'[{time.monotonic() - begin:.0f} s]')
    except AxisTestError:
        with contextlib.suppress(AxisTestError):
            port.home()
        raise
    port.home()
    return markers


# -- the ROS port -------------------------------------------------------------------------------
class CellPort:
    """:class:`Port` on the running cell through ``client`` (its own subscriptions to the
    encoders, the tracker and the truth, and the marker publisher; ``timeout`` s for a call or
    the readings of a stop)."""

    def __init__(self, client: CellClient, timeout: float = 30.0) -> None:
        self.client, self.timeout = client, timeout
        self._lock = threading.Lock()
        self._joints: deque[tuple[float, FloatArray]] = deque(maxlen=HISTORY)
        self._true: deque[tuple[float, FloatArray]] = deque(maxlen=HISTORY)
        self._poses: deque[tuple[float, FloatArray, FloatArray]] = deque(maxlen=HISTORY)
        node = client.node
        node.create_subscription(JointState, names.JOINT_STATES,
                                 lambda m: self._on_joints(self._joints, m), STREAM_QOS)
        node.create_subscription(JointState, names.TRUE_JOINT_STATES,
                                 lambda m: self._on_joints(self._true, m), STREAM_QOS)
        node.create_subscription(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                 self._on_pose, STREAM_QOS)
        self._markers = client.node.create_publisher(String, names.AXIS_TEST, MARKER_QOS)

    def _on_joints(self, into: deque[tuple[float, FloatArray]], msg: Any) -> None:
        values = joint_values(msg, JOINT_NAMES)
        if values is not None:
            with self._lock:
                into.append((seconds(msg.header.stamp), values))

    def _on_pose(self, msg: Any) -> None:
        p, q = pose_arrays(msg.pose.pose)
        with self._lock:
            self._poses.append((seconds(msg.header.stamp), np.asarray(p), np.asarray(q)))

    def now(self) -> float:
        """The cell's clock, s."""
        return float(self.client.node.get_clock().now().nanoseconds * 1e-9)

    def home(self) -> None:
        try:
            done, message = self.client.home(max(self.timeout, 60.0))
        except TimeoutError as err:
            raise AxisTestError(f'homing: {err}') from err
        if not done:
            raise AxisTestError(f'homing failed: {message}')

    def joints(self) -> FloatArray:
        try:
            wait_until(lambda: self._joints, self.timeout, f'an encoder reading on '
                       f'{names.JOINT_STATES}')
        except TimeoutError as err:
            raise AxisTestError(str(err)) from err
        with self._lock:
            return self._joints[-1][1].copy()

    def jog(self, axis: str, delta: float) -> None:
        try:
            answer = self.client.call(Jog, names.JOG, Jog.Request(axis=axis, delta=float(delta)),
                                      max(self.timeout, 60.0))
        except TimeoutError as err:
            raise AxisTestError(f'jog {axis}: {err}') from err
        if not answer.success:
            raise AxisTestError(f'jog {axis} by {delta:+.7g} refused or aborted '
                                f'({answer.code_name}): {answer.reason}', str(answer.code_name))

    def rest(self, seconds: float) -> None:
        time.sleep(seconds)

    def _since(self, start: float) -> list[tuple[float, FloatArray, FloatArray]]:
        with self._lock:
            return [entry for entry in self._poses if entry[0] >= start]

    def measure(self, samples: int) -> Readings:
        start = self.now()
        try:
            wait_until(lambda: len(self._since(start)) >= samples, self.timeout,
                       f'{samples} tracker readings on {names.MEASURED_POSE}')
        except TimeoutError as err:
            raise AxisTestError(str(err)) from err
        taken = sorted(self._since(start), key=lambda e: e[0])[:samples]
        end = taken[-1][0]
        with self._lock:
            encoder = [v for t, v in self._joints if start <= t <= end]
            latest = self._joints[-1][1] if self._joints else None
            true = [v for t, v in self._true if start <= t <= end]
        if not encoder:
            if latest is None:
                raise AxisTestError(f'no encoder reading on {names.JOINT_STATES}')
            encoder = [latest]
        return Readings(np.array([e[1] for e in taken]), np.array([e[2] for e in taken]),
                        np.mean(encoder, axis=0), np.mean(true, axis=0) if true else None,
                        start, end)

    def publish(self, marker: AxisTestMarker) -> None:
        self._markers.publish(String(data=marker.to_json()))


def reference_machine(client: CellClient, settings: PositionerSettings) -> Reference:
    """The positioner's own machine model: the calibration file it has loaded
    (``compensation.calibration_file``), else the nominal machine of ``settings``."""
    path = str(client.get_parameter(names.NODE_POSITIONER, CALIBRATION_FILE) or '')
    if not path:
        return Reference(MachineModel(settings.mechanism), NOMINAL)
    model = calfile.load(path, settings.mechanism).model(settings.mechanism, settings.payload,
                                                         settings.structure)
    return Reference(model, CALIBRATED)


def simulation_truth(config: Path) -> MachineModel | None:
    """Judging only: the simulator's true machine in the parameter file ``config`` (None
    without a simulator section)."""
    params = node_parameters(load_parameter_file(config), names.NODE_MEASUREMENT)
    if not params:
        return None
    return parse(PoseMeasurementSettings, params).true_machine()


def run_live(client: CellClient, test: AxisTest, config: Path, say: Callable[[str], None], *,
             judge: bool = True, timeout: float = 30.0) -> tuple[list[AxisTestMarker],
                                                                  AxisTestResults]:
    """The axis test on the cell of ``client`` with the positioner's machine of ``config``
    (its jog steps and speeds, its calibration if loaded) and, with ``judge``, the simulator's
    truth of ``config``: the markers and their ISO 230-2 figures."""
    settings = machine_settings(config)
    op = settings.operator
    reference = reference_machine(client, settings)
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
    port = CellPort(client, timeout)
    # Mode none while it runs, as calibrate_cell measures: the home pose is the nominal
    # machine's (the home values the program was checked at) and a jog, outside the
    # kinematics anyway, does not depend on the tracker's liveness.
    previous = str(client.get_parameter(names.NODE_POSITIONER, MODE))
    result = client.set_parameter(names.NODE_POSITIONER, MODE, 'none')
    if not result.successful:
        raise AxisTestError(f'the positioner refused {MODE} = none: {result.reason}')
    try:
        markers = run_procedure(port, test, reference,
                                (op.jog_largest_length_step, op.jog_largest_theta_step), say,
                                truth=truth)
    finally:
        client.set_parameter(names.NODE_POSITIONER, MODE, previous)
    say(f'the recorder took the markers ({names.AXIS_TEST})'
        if client.subscribed(names.AXIS_TEST, names.NODE_RECORDER)
        else f'no recorder took the markers ({names.AXIS_TEST}): not in a bag')
    return markers, axis_test_figures(markers)


def write(results: AxisTestResults, out: Path) -> tuple[Path, Path]:
    """``axis_test.md`` (the tables) and ``axis_test.json`` in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    md, js = out / 'axis_test.md', out / 'axis_test.json'
    md.write_text('# Axis test (ISO 230-2:2014)\n\n' + '\n'.join(results.markdown()) + '\n')
    js.write_text(json.dumps(results.to_dict(), indent=1))
    return md, js


def say(text: str) -> None:
    """A progress line, at once."""
    print(text, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(
        prog='axis_test', description='The axis test (ISO 230-2:2014 per actuator) on the '
        'running cell of ROS_DOMAIN_ID: a line per measured stop, then the ISO 230-2 tables.')
    parser.add_argument('--program', type=Path, help='axis-test file (default: the shipped '
                        'config/axis_test.yaml)')
    parser.add_argument('--config', type=Path, help='parameter file of the cell (default: the '
                        'shipped config/cell.yaml): the machine, and the truth to judge by')
    parser.add_argument('--out', type=Path, help='write axis_test.md and axis_test.json here')
    parser.add_argument('--no-truth', action='store_true',
                        help='do not judge by the simulator\'s truth')
    args = parser.parse_args(argv)
    try:
        config = args.config or config_path('cell.yaml')
        settings = machine_settings(config)
        test = load_axis_test(args.program or config_path('axis_test.yaml'), settings.mechanism)
    except PositioningError as err:
        say(f'axis_test: error: {err}')
        return EXIT_UNUSABLE

    def on_signal(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    client = CellClient(name='axis_test', signals=False)
    try:
        _, results = run_live(client, test, config, say, judge=not args.no_truth)
    except KeyboardInterrupt:
        with contextlib.suppress(Exception):
            client.trigger(names.STOP, 10.0)
        say('axis_test: interrupted: drives stopped')
        return EXIT_INTERRUPTED
    except (AxisTestError, TimeoutError, PositioningError) as err:
        say(f'axis_test: error: {err}')
        return EXIT_UNUSABLE
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        client.close()
    say('\n'.join(results.summary()))
    say('\n'.join(results.markdown()))
    if args.out is not None:
        md, js = write(results, args.out)
        say(f'tables: {md}\nJSON:   {js}')
    return EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
