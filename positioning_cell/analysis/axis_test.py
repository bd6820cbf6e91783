"""The axis test (``config/axis_test.yaml``, ``run_cell --axis-test``): each actuator tested
alone by the standard test of ISO 230-2:2014, the other joints at home; pure library (no ROS).

- the program: parsed and checked against the mechanism before anything moves
  (:func:`axis_test_from`, :func:`load_axis_test`);
- its stops in the standard's linear cycle order (:meth:`AxisTest.stops`);
- the marker published on ``/cell/axis_test`` per measured stop (:class:`AxisTestMarker`,
  JSON), as the live procedure (``positioning_cell.tools.axis_test``) sends it and a bag keeps
  it;
- from markers, the ISO 230-2 figures per axis and per reference source, with their JSON
  document and Markdown tables (:func:`axis_test_figures`, :class:`AxisTestResults`).

Axis coordinates: an axis's value is its leg length (m) or second U angle θ (rad) as the
drives count it (the encoder coordinate). The target position of a stop is the axis's home
value plus the program's target; the actual position is the real actuator value: from the
tracker, the inverse kinematics of the averaged measured pose through the cell's machine model
(the calibrated machine, whose real joint is its encoder value plus its identified zero
offset, or the nominal one); in simulation, for judging only, the true axis position plus the
truth's zero offset. So the deviation x = actual − target holds the axis's zero offset, its
positioning error and, from the tracker, what the model leaves of the machine's geometry.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.iso230_2 import (
    AXIS_FIGURES,
    STANDARD,
    UNITS,
    AxisFigures,
    iso230_2,
)
from positioning_cell.accuracy.iso230_2_uncertainty import axis_figure_uncertainty
from positioning_cell.calibration.machine import MachineModel
from positioning_cell.config import load_parameter_file
from positioning_cell.core.kinematics import forward, inverse
from positioning_cell.core.limits import check_poses
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.files import brief_errors, excerpt
from positioning_cell.limits.jog import LINEAR_AXES, axis_range

FloatArray = NDArray[np.float64]

UP, DOWN = 'up', 'down'
#: The reference sources of the actual positions: the tracker through the cell's model, and
#: (simulation, judging only) the truth.
TRACKER, TRUTH = 'tracker', 'truth'
SOURCES = (TRACKER, TRUTH)
#: Which machine model turned the tracker's pose into actuator values.
CALIBRATED, NOMINAL = 'calibrated', 'nominal'
#: Points checked along each axis's travel (besides every stop).
TRAVEL_CHECKS = 25
#: Display units of the tables: deviations, targets.
LENGTH_UNITS, THETA_UNITS = ('um', 'mm'), ('urad', 'mrad')


def is_linear(axis: str) -> bool:
    """A leg length (m) rather than a θ axis (rad)."""
    return JOINT_NAMES.index(axis) < LINEAR_AXES


def _amount(axis: str, value: float) -> str:
    """A value of ``axis`` for people: mm or mrad."""
    return f'{value * 1e3:+.4f} {"mm" if is_linear(axis) else "mrad"}'


# -- the program -------------------------------------------------------------------------------
@dataclass(frozen=True)
class AxisPlan:
    """One axis of the test: its joint name, the target positions P_i relative to its home
    value (strictly increasing; m or rad) and the overshoot beyond the end targets before each
    reversal (> 0, m or rad)."""

    axis: str
    targets: tuple[float, ...]
    overshoot: float


@dataclass(frozen=True)
class Stop:
    """Where the axis goes next: ``position`` relative to its home value (m or rad), whether it
    is ``measured`` (a target; else an overshoot or the return home), the target ``index``
    (0-based; None when not measured), the ``direction`` of the approach (up, down) and the
    ``cycle`` (1-based; 0 for the approach before the first cycle and the return home)."""

    axis: str
    position: float
    measured: bool
    index: int | None
    direction: str
    cycle: int


@dataclass(frozen=True)
class AxisTest:
    """The axis test: the ``axes`` in order, ``cycles`` n (>= 2), ``samples`` tracker readings
    averaged per measured stop (>= 1) and ``dwell`` s at rest before them (>= 0)."""

    axes: tuple[AxisPlan, ...]
    cycles: int = 5
    samples: int = 5
    dwell: float = 0.1

    def plan(self, axis: str) -> AxisPlan:
        """The plan of ``axis`` (KeyError if it is not tested)."""
        for plan in self.axes:
            if plan.axis == axis:
                return plan
        raise KeyError(axis)

    def stops(self, axis: str | None = None) -> list[Stop]:
        """The stops of one axis (default: of every axis, in order), in ISO 230-2's linear
        cycle: P_1 − overshoot; per cycle P_1 … P_m upwards (measured), P_m + overshoot,
        P_m … P_1 downwards (measured), then P_1 − overshoot before the next cycle; finally
        back to the home value (position 0)."""
        if axis is None:
            return [s for plan in self.axes for s in self.stops(plan.axis)]
        plan = self.plan(axis)
        p, over = plan.targets, plan.overshoot
        out = [Stop(axis, p[0] - over, False, None, DOWN if p[0] - over < 0.0 else UP, 0)]
        for cycle in range(1, self.cycles + 1):
            out += [Stop(axis, x, True, i, UP, cycle) for i, x in enumerate(p)]
            out.append(Stop(axis, p[-1] + over, False, None, UP, cycle))
            out += [Stop(axis, p[i], True, i, DOWN, cycle) for i in reversed(range(len(p)))]
            if cycle < self.cycles:
                out.append(Stop(axis, p[0] - over, False, None, DOWN, cycle))
        out.append(Stop(axis, 0.0, False, None, UP if p[0] < 0.0 else DOWN, 0))
        return out

    @property
    def measured_stops(self) -> int:
        """Measured stops of the whole test: Σ 2·n·m."""
        return sum(2 * self.cycles * len(plan.targets) for plan in self.axes)

    def duration(self, length_speed: float, length_acceleration: float, theta_speed: float,
                 theta_acceleration: float, settle_time: float, tracker_rate: float,
                 overhead: float = 0.25) -> float:
        """Estimated cell time of the test, s: every move at the jog's speed profile (m/s,
        m/s², rad/s, rad/s²) plus the positioner's ``settle_time`` and ``overhead`` (the
        call and the arrival), and at each measured stop the dwell and ``samples`` readings
        at ``tracker_rate`` Hz."""
        total = 0.0
        for plan in self.axes:
            v, a = ((length_speed, length_acceleration) if is_linear(plan.axis)
                    else (theta_speed, theta_acceleration))
            here = 0.0
            for stop in self.stops(plan.axis):
                total += move_time(abs(stop.position - here), v, a) + settle_time + overhead
                if stop.measured:
                    total += self.dwell + self.samples / tracker_rate
                here = stop.position
        return total


def move_time(distance: float, speed: float, acceleration: float) -> float:
    """Duration of a move of ``distance`` at a trapezoidal speed profile (triangular when too
    short to reach ``speed``), as a jog moves (positioning_cell.limits.jog.jog_trajectory)."""
    if distance <= 0.0:
        return 0.0
    if speed * speed / acceleration >= distance:
        return 2.0 * math.sqrt(distance / acceleration)
    return 2.0 * speed / acceleration + (distance - speed * speed / acceleration) / speed


def home_joints(mech: Mechanism) -> FloatArray:
    """The six axis values (m, rad; JOINT_NAMES order) of the nominal machine at home."""
    joints = inverse(mech, mech.home_position, mech.home_quaternion)
    return np.concatenate([joints.lengths[0], joints.thetas[0]])


def _integer(block: Mapping[str, Any], key: str, default: int, low: int) -> int:
    value = block.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(f'axis_test.{key} = {excerpt(value)}: must be an integer >= {low}')
    return value


def _number(value: Any, name: str, *, positive: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value) or (value <= 0.0 if positive else value < 0.0):
        raise ConfigError(f'{name} = {excerpt(value)}: must be a number '
                          f'{"> 0" if positive else ">= 0"}')
    return float(value)


def _finite(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value):
        raise ConfigError(f'{name} = {excerpt(value)}: must be a finite number')
    return float(value)


def _plan(axis: Any, spec: Any) -> AxisPlan:
    name = f'axis_test.axes.{axis}'
    if axis not in JOINT_NAMES:
        raise ConfigError(f'{name}: unknown axis: one of {", ".join(JOINT_NAMES)}')
    if not isinstance(spec, Mapping):
        raise ConfigError(f'{name}: expected {{targets: [P_1, ..., P_m], overshoot: d}}')
    unknown = sorted(set(spec) - {'targets', 'overshoot'})
    if unknown:
        raise ConfigError(f'{name}.{unknown[0]}: unknown key (targets, overshoot)')
    targets = spec.get('targets')
    if not isinstance(targets, list) or len(targets) < 2:
        raise ConfigError(f'{name}.targets = {excerpt(targets)}: a list of at least 2 target '
                          'positions '
                          '(ISO 230-2: at least 5)')
    values = tuple(_finite(v, f'{name}.targets[{i}]') for i, v in enumerate(targets))
    for i in range(1, len(values)):
        if not values[i] > values[i - 1]:
            raise ConfigError(f'{name}.targets[{i}] = {excerpt(values[i])}: the targets must be '
                              f'strictly increasing (targets[{i - 1}] = {excerpt(values[i - 1])})')
    return AxisPlan(str(axis), values, _number(spec.get('overshoot'), f'{name}.overshoot',
                                               positive=True))


def axis_test_from(data: Mapping[str, Any], mech: Mechanism) -> AxisTest:
    """The axis test in a parsed file (``axis_test:`` block, see config/axis_test.yaml),
    checked with :func:`check_axis_test`. ConfigError names what is wrong."""
    block = data.get('axis_test')
    if not isinstance(block, Mapping):
        raise ConfigError('axis test file: no "axis_test:" mapping')
    unknown = sorted(set(block) - {'cycles', 'samples', 'dwell', 'axes'})
    if unknown:
        raise ConfigError(f'axis_test.{unknown[0]}: unknown key (cycles, samples, dwell, axes)')
    axes = block.get('axes')
    if not isinstance(axes, Mapping) or not axes:
        raise ConfigError('axis_test.axes: expected a mapping of joint names '
                          f'({", ".join(JOINT_NAMES)}) to {{targets: [...], overshoot: d}}')
    test = AxisTest(tuple(_plan(axis, spec) for axis, spec in axes.items()),
                    _integer(block, 'cycles', 5, 2), _integer(block, 'samples', 5, 1),
                    _number(block.get('dwell', 0.1), 'axis_test.dwell', positive=False))
    check_axis_test(test, mech)
    return test


def check_axis_test(test: AxisTest, mech: Mechanism) -> None:
    """Refuse (ConfigError naming the axis, the position and the limit) a test whose stops
    leave the axis's range, or that takes the platform, with the other joints at the nominal
    home, out of the workspace or out of any limit of ``mech`` anywhere along its travel
    (:func:`positioning_cell.core.limits.check_poses`)."""
    home = home_joints(mech)
    for plan in test.axes:
        k = JOINT_NAMES.index(plan.axis)
        name = f'axis_test.axes.{plan.axis}'
        positions = np.array([s.position for s in test.stops(plan.axis)])
        low, high = axis_range(mech, k)
        for x in (float(positions.min()), float(positions.max())):
            if not low <= home[k] + x <= high:
                raise ConfigError(f'{name}: the stop at {_amount(plan.axis, x)} from home '
                                  f'takes the axis to {_amount(plan.axis, home[k] + x)}, '
                                  f'outside its range [{_amount(plan.axis, low)}, '
                                  f'{_amount(plan.axis, high)}]')
        travel = np.union1d(positions, np.linspace(positions.min(), positions.max(),
                                                   TRAVEL_CHECKS))
        position, quaternion = _platform_along(mech, home, k, travel, plan.axis, name)
        report = check_poses(mech, position, quaternion)
        if not report.ok:
            first = report.violations[0]
            what = first.describe().split(': ', 1)[-1]  # without its sample number
            raise ConfigError(f'{name}: at {_amount(plan.axis, float(travel[first.sample]))} '
                              f'from home, with the other joints at home, the platform is '
                              f'outside the limits: {what}')


def _platform_along(mech: Mechanism, home: FloatArray, k: int, travel: FloatArray, axis: str,
                    name: str) -> tuple[FloatArray, FloatArray]:
    """The platform poses (N, 3), (N, 4) with axis ``k`` at ``home[k] + travel`` (N,)
    (sorted, holding 0) and the others at home: forward kinematics marching out from home in
    both directions, each point started from its neighbour's passive angles (the branch the
    machine follows). ConfigError where there is no pose."""
    position, quaternion = np.zeros((travel.size, 3)), np.zeros((travel.size, 4))
    zero = int(np.argmin(np.abs(travel)))
    for order in (range(zero, travel.size), range(zero, -1, -1)):
        phis = None
        for i in order:
            joints = home.copy()
            joints[k] += travel[i]
            pose = forward(mech, joints[None, :3], joints[None, 3:], phis)
            if not pose.converged[0]:
                raise ConfigError(f'{name}: at {_amount(axis, float(travel[i]))} from home the '
                                  'platform leaves the workspace (no pose of the machine '
                                  'there)')
            position[i], quaternion[i], phis = pose.position[0], pose.quaternion[0], pose.phis
    return position, quaternion


def load_axis_test(path: str | Path, mech: Mechanism) -> AxisTest:
    """Read and check an axis-test file (:func:`axis_test_from`)."""
    data = load_parameter_file(path)
    with brief_errors():
        return axis_test_from(data, mech)


# -- what the live procedure measures ------------------------------------------------------------
def actuator_values(model: MachineModel, position: ArrayLike, quaternion: ArrayLike) -> FloatArray:
    """The real actuator values (6,) (JOINT_NAMES order, m and rad) that put the machine
    ``model`` on the pose (3,) m, (4,) x, y, z, w in ``base``: its inverse kinematics (with its
    clearance) plus nothing else; its encoders would read these minus its zero offsets."""
    commands = model.commands(position, quaternion)
    return np.concatenate([commands.lengths[0] + model.length_offsets,
                           commands.thetas[0] + model.theta_offsets])


#: The steps (m, rad) of the finite differences of :func:`actuator_uncertainty`.
POSE_STEPS = (1e-6, 1e-6)


def actuator_uncertainty(model: MachineModel, position: ArrayLike, quaternion: ArrayLike,
                         covariance: ArrayLike) -> FloatArray:
    """The standard uncertainty (6,) (m, rad; JOINT_NAMES order) of :func:`actuator_values`
    of a pose (3,) m, (4,) measured with covariance (6, 6) (x, y, z, then small rotations
    about the base axes, R' = exp([δθ]×)·R; m², rad²): √diag(J Σ Jᵀ), J the central finite
    differences (:data:`POSE_STEPS`) of the actuator values over the pose's six directions
    (the law of propagation, JCGM 100 eq. 13: the errors are µm, the kinematics smooth over
    them). NaN where the covariance is not stated (a NaN in it)."""
    cov = np.asarray(covariance, dtype=float)
    if not np.all(np.isfinite(cov)):
        return np.full(6, math.nan)
    p = np.asarray(position, dtype=float)
    rotation = scipy_rotation().from_quat(quaternion)
    jac = np.empty((6, 6))
    for d in range(6):  # the pose's six directions, not samples
        step = np.zeros(6)
        step[d] = POSE_STEPS[d // 3]
        values = [actuator_values(model, p + sign * step[:3],
                                  (scipy_rotation().from_rotvec(sign * step[3:]) * rotation
                                   ).as_quat()) for sign in (1.0, -1.0)]
        jac[:, d] = (values[0] - values[1]) / (2.0 * step[d])
    out: FloatArray = np.sqrt(np.maximum(np.diagonal(jac @ cov @ jac.T), 0.0))
    return out


@dataclass(frozen=True)
class AxisTestMarker:
    """One measured stop of an axis test, as published on ``/cell/axis_test`` (JSON): the
    ``run`` (its start, UTC ISO 8601: a bag may hold several), the ``axis``, the target
    ``index`` i (0-based) and ``target`` P_i relative to the home value, the ``direction`` of
    the approach (up, down) and the ``cycle`` (1-based); the axis values (m or rad, absolute,
    encoder coordinate): ``commanded`` (home value + target), ``encoder`` (the mean of the
    axis's encoder readings over the window), ``tracker`` (the real actuator value from the
    averaged tracker pose through the ``reference`` model, calibrated or nominal) and ``true``
    (simulation only, judging: the true axis position plus the truth's zero offset; None
    elsewhere); the window of tracker readings used, ``start`` … ``end`` (s, the cell's clock),
    and their number ``samples``; ``tracker_u`` the standard uncertainty of ``tracker`` from
    the averaged pose's covariance (:func:`actuator_uncertainty`; None: not stated, e.g. a
    bag recorded before it was)."""

    run: str
    axis: str
    index: int
    target: float
    direction: str
    cycle: int
    commanded: float
    encoder: float
    tracker: float
    true: float | None
    start: float
    end: float
    samples: int
    reference: str = NOMINAL
    tracker_u: float | None = None

    def to_json(self) -> str:
        """The JSON text published on /cell/axis_test."""
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> AxisTestMarker:
        """A marker from its JSON (InputError naming what is wrong)."""
        try:
            d = json.loads(text)
            missing = [f.name for f in fields(cls)
                       if f.name not in d and f.name not in ('reference', 'tracker_u')]
            if missing:
                raise KeyError(', '.join(missing))
            true, tracker_u = d['true'], d.get('tracker_u')
            marker = cls(str(d['run']), str(d['axis']), int(d['index']), float(d['target']),
                         str(d['direction']), int(d['cycle']), float(d['commanded']),
                         float(d['encoder']), float(d['tracker']),
                         None if true is None else float(true), float(d['start']),
                         float(d['end']), int(d['samples']), str(d.get('reference', NOMINAL)),
                         None if tracker_u is None else float(tracker_u))
        except (ValueError, KeyError, TypeError) as err:
            raise InputError(f'not an axis-test marker: {text[:80]!r} ({err})') from None
        values = [marker.target, marker.commanded, marker.encoder, marker.tracker,
                  marker.start, marker.end] + ([] if marker.true is None else [marker.true])
        why = ('unknown axis' if marker.axis not in JOINT_NAMES
               else 'direction not up or down' if marker.direction not in (UP, DOWN)
               else 'index, cycle or samples out of range' if (
                   marker.index < 0 or marker.cycle < 1 or marker.samples < 1)
               else 'reference not calibrated or nominal' if marker.reference not in (
                   CALIBRATED, NOMINAL)
               else 'a value is not finite' if not all(map(math.isfinite, values))
               else 'tracker_u negative or not finite' if marker.tracker_u is not None and not (
                   math.isfinite(marker.tracker_u) and marker.tracker_u >= 0.0)
               else '')
        if why:
            raise InputError(f'not an axis-test marker ({why}): {text[:80]!r}')
        return marker

    def deviation(self, source: str) -> float | None:
        """x = actual − target of ``source`` (tracker, truth), m or rad; None without it."""
        value = self.tracker if source == TRACKER else self.true
        return None if value is None else value - self.commanded


def parse_markers(texts: Sequence[str]) -> tuple[list[AxisTestMarker], list[str]]:
    """Markers from /cell/axis_test message texts, and a line per text that is not one."""
    markers, problems = [], []
    for text in texts:
        try:
            markers.append(AxisTestMarker.from_json(text))
        except InputError as err:
            problems.append(str(err))
    return markers, problems


def runs(markers: Sequence[AxisTestMarker]) -> list[str]:
    """The runs the markers belong to, in order of their first marker."""
    return list(dict.fromkeys(m.run for m in sorted(markers, key=lambda m: m.start)))


# -- the figures --------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class AxisResult:
    """The ISO 230-2 figures of one axis from one source (tracker, truth), SI (m or rad):
    ``figures`` over the targets relative to the home value, the ``cycles`` used (1-based) and
    the ``reference`` model of the tracker's values."""

    axis: str
    source: str
    figures: AxisFigures
    cycles: tuple[int, ...]
    reference: str
    #: U (k = 2) of each axis figure from the stops' stated uncertainties, by its name
    #: (:func:`~positioning_cell.accuracy.iso230_2_uncertainty.axis_figure_uncertainty`);
    #: None: not stated (the truth, or a stop without ``tracker_u``).
    uncertainty: dict[str, float] | None = None

    @property
    def units(self) -> tuple[str, str]:
        """Display units (deviations, targets): µm and mm for a leg, µrad and mrad for θ."""
        return LENGTH_UNITS if is_linear(self.axis) else THETA_UNITS

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: axis, source, reference, unit (m or rad), cycles and the figures."""
        return {'axis': self.axis, 'source': self.source, 'reference': self.reference,
                'unit': 'm' if is_linear(self.axis) else 'rad', 'cycles': list(self.cycles),
                **self.figures.to_dict(), 'U': self.uncertainty}

    def title(self) -> str:
        """Which axis, from which source, in which unit."""
        what = (f'tracker (inverse kinematics of the measured pose, {self.reference} machine)'
                if self.source == TRACKER else 'simulation truth (judging only)')
        unit, target = self.units
        symbol = {'um': 'µm', 'urad': 'µrad'}[unit]
        return (f'{self.axis}: {what}; n = {self.figures.cycles}, m = '
                f'{self.figures.positions}; deviations in {symbol}, targets in {target} from '
                'home')

    def summary(self) -> str:
        """One line: the axis figures A, R, B, E, M and the mean deviation."""
        f = self.figures
        unit = self.units[0]
        scale, symbol = (1e6, 'µm') if unit == 'um' else (1e6, 'µrad')
        mean = float(np.mean(f.x_mean))
        return (f'{self.axis:<12} {self.source:<7} A {f.A * scale:8.2f}  R {f.R * scale:7.2f}  '
                f'B {f.B * scale:6.2f}  E {f.E * scale:8.2f}  M {f.M * scale:8.2f}  '
                f'mean x {mean * scale:+9.2f} {symbol}')


@dataclass(frozen=True)
class AxisTestResults:
    """The figures of one axis-test run: per axis (in test order) per source (tracker, then
    truth when the markers carry it) an :class:`AxisResult`; ``notes`` say what was left out
    and why."""

    run: str | None
    results: tuple[AxisResult, ...]
    notes: tuple[str, ...] = field(default=())

    def by_axis(self) -> dict[str, dict[str, AxisResult]]:
        """axis → source → result."""
        out: dict[str, dict[str, AxisResult]] = {}
        for r in self.results:
            out.setdefault(r.axis, {})[r.source] = r
        return out

    def __iter__(self) -> Iterator[AxisResult]:
        return iter(self.results)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: the standard, the run, the results and the notes."""
        return {'standard': STANDARD, 'run': self.run,
                'results': [r.to_dict() for r in self.results], 'notes': list(self.notes)}

    def markdown(self, level: int = 3) -> list[str]:
        """Markdown lines for the report: per axis and source a heading at ``level``, the
        table of the targets (P_i, x̄↑, x̄↓, x̄, s↑, s↓, R_i↑, R_i↓, R_i, B_i) and the row of
        the axis figures (A, A↑, A↓, R, R↑, R↓, B, B̄, E, E↑, E↓, M); then the notes."""
        lines: list[str] = []
        for r in self.results:
            unit, target = r.units
            lines += ['#' * level + ' ' + r.title(), '']
            lines += r.figures.markdown(unit, target_unit=target)
            if r.uncertainty is not None:
                factor, decimals = UNITS[unit][0], UNITS[unit][3]
                lines.append('| ' + ' | '.join(
                    f'± {r.uncertainty[name] * factor:.{decimals}f}' for name, _ in AXIS_FIGURES)
                    + ' |')
                lines += ['', 'Second row: U (k = 2) of each axis figure from the tracker\'s '
                          'stated uncertainty of each stop (a bound whatever the truth; '
                          'positioning_cell.accuracy.iso230_2_uncertainty).']
            lines.append('')
        if not self.results:
            lines += ['No axis-test figures.', '']
        lines += [f'- {note}' for note in self.notes]
        return lines

    def summary(self) -> list[str]:
        """A line per axis and source (:meth:`AxisResult.summary`)."""
        return [r.summary() for r in self.results]


def axis_test_figures(markers: Sequence[AxisTestMarker], run: str | None = None,
                      sources: Sequence[str] = SOURCES) -> AxisTestResults:
    """The ISO 230-2 figures per axis and source from the markers of run ``run`` (default:
    the last run of the markers): per axis, the targets P_i relative to home, and for each
    source the actual positions P_i + x (x = actual − commanded) of each cycle up and down. A
    cycle lacking a stop of either direction, or a value of the source, is left out (noted);
    an axis with fewer than 2 complete cycles or 2 targets gets no figures from that source
    (noted). The truth is a source only when the markers carry it. A stop measured twice
    counts once: the later marker."""
    found = runs(markers)
    if not found:
        return AxisTestResults(None, (), ('no axis-test marker',))
    if run is None:
        run = found[-1]
    elif run not in found:
        raise InputError(f'no axis-test run {run!r}; the markers hold {", ".join(found)}')
    notes: list[str] = []
    chosen = sorted((m for m in markers if m.run == run), key=lambda m: m.start)
    axes = list(dict.fromkeys(m.axis for m in chosen))
    results: list[AxisResult] = []
    for axis in axes:
        stops = {(m.cycle, m.direction, m.index): m for m in chosen if m.axis == axis}
        targets = {m.index: m.target for m in stops.values()}
        indexes = sorted(targets)
        if indexes != list(range(len(indexes))) or len(indexes) < 2:
            notes.append(f'{axis}: targets {indexes} measured: not a complete set of at least '
                         '2 targets, no figures')
            continue
        cycles = sorted({c for c, _, _ in stops})
        reference = next(iter(stops.values())).reference
        for source in sources:
            if source == TRUTH and all(m.true is None for m in stops.values()):
                continue
            complete = [c for c in cycles if all(
                (c, d, i) in stops and stops[c, d, i].deviation(source) is not None
                for d in (UP, DOWN) for i in indexes)]
            left = sorted(set(cycles) - set(complete))
            if left:
                notes.append(f'{axis} ({source}): cycle(s) {left} incomplete, left out')
            if len(complete) < 2:
                notes.append(f'{axis} ({source}): {len(complete)} complete cycle(s), ISO 230-2 '
                             'needs at least 2: no figures')
                continue
            p = np.array([targets[i] for i in indexes])
            up, down = (_actual(stops, complete, p, direction, source)
                        for direction in (UP, DOWN))
            figures = iso230_2(p, up, down)
            u = [[[stops[c, d, i].tracker_u for i in indexes] for c in complete]
                 for d in (UP, DOWN)]
            stated = source == TRACKER and all(v is not None for d in u for c in d for v in c)
            results.append(AxisResult(
                axis, source, figures, tuple(complete), reference,
                axis_figure_uncertainty(figures, *np.array(u, dtype=float)) if stated
                else None))
    return AxisTestResults(run, tuple(results), tuple(notes))


def _actual(stops: Mapping[tuple[int, str, int], AxisTestMarker], cycles: Sequence[int],
            targets: FloatArray, direction: str, source: str) -> FloatArray:
    """P_ij = P_i + x_ij (n, m) of ``source`` in ``direction`` (every stop is there)."""
    rows = []
    for c in cycles:
        row = []
        for i, p in enumerate(targets):
            x = stops[c, direction, i].deviation(source)
            assert x is not None
            row.append(p + x)
        rows.append(row)
    return np.array(rows, dtype=float)
