"""The positioner's settings: every parameter of the ``positioner`` node (config/cell.yaml),
grouped by what it governs. SI units."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance import ClearanceModel, ClearanceParameters, build
from positioning_cell.config import load_parameter_file, merged, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.limits.axis_ranges import AxisRangeSettings
from positioning_cell.limits.boxes import FactoryBoxSettings
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.motion.standstill import StandstillSettings
from positioning_cell.motion.temperature import TemperatureSettings
from positioning_cell.moves.trajectory import MotionLimits
from positioning_cell.names import NODE_DRIVER, NODE_MEASUREMENT, NODE_POSITIONER
from positioning_cell.parameters import ParameterError, check_fields, group, parse, setting

FloatArray = NDArray[np.float64]


class CompensationMode(Enum):
    """none: nominal IK; model: the configured clearance model; measured: the model, then
    closed-loop correction from the measured pose."""

    NONE = 'none'
    MODEL = 'model'
    MEASURED = 'measured'


@dataclass(frozen=True)
class CompensationSettings:
    """The ``compensation:`` block."""

    mode: str = setting('measured', 'none: nominal inverse kinematics; model: the clearance '
                        'model; measured: the model, then closed loop on the tracker',
                        choices=tuple(m.value for m in CompensationMode), dynamic=True)
    clearance: ClearanceParameters = group(
        ClearanceParameters, 'the a-priori clearance model of model and measured, used while '
        'no calibration is loaded')
    calibration_file: str = setting(
        '', 'calibration.yaml of this machine (calibrate_cell): model and measured use the '
        'identified machine; empty: the a-priori clearance model', dynamic=True)
    max_iterations: int = setting(5, 'closed-loop corrections per move', low=0, high=50,
                                  dynamic=True)
    samples: int = setting(10, 'tracker samples averaged per correction', low=1, high=200,
                           dynamic=True)
    min_samples: int = setting(
        3, 'tracker samples after which an averaged reading may end early: once its error is '
        'within the goal tolerance by 2 standard deviations of what the samples still to come '
        'could change (before a move: within or outside it beyond 2 standard uncertainties; '
        'samples or more: never early)', low=3, high=200, dynamic=True)
    carry_distance: float = setting(
        0.01, 'measured: a goal this close to recently settled goals starts with their '
        'corrections beyond the readings\' noise (affine fit; 0: never)', 'm', low=0.0,
        high=1.0, dynamic=True)
    carry_angle: float = setting(
        0.05, '... and whose orientation differs from it by at most this', 'rad', low=0.0,
        high=3.2, dynamic=True)
    temperature: TemperatureSettings = group(
        TemperatureSettings, 'the measured air temperature (/cell/air_temperature) the '
        'calibrated thermal terms use')

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class GoalTolerance:
    """The settle tolerance of a move (a request's tolerance overrides the position)."""

    position: float = setting(10e-6, 'settle tolerance of a move, position', 'm', low=0.0,
                              low_open=True, high=0.01, dynamic=True)
    orientation: float = setting(1e-4, 'settle tolerance of a move, orientation', 'rad',
                                 low=0.0, low_open=True, high=0.1, dynamic=True)
    largest_request: float = setting(1e-3, 'largest settle tolerance a request may ask for',
                                     'm', low=0.0, low_open=True, high=0.01, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.position > self.largest_request:
            raise ParameterError('position', self.position,
                                 f'must not exceed largest_request = {self.largest_request} m')

    def for_request(self, tolerance: float) -> GoalTolerance:
        """The tolerance of a move that asked for ``tolerance`` m (0: this one); InputError
        when it is not finite, negative or above ``largest_request``."""
        if not (math.isfinite(tolerance) and 0.0 <= tolerance <= self.largest_request):
            raise InputError(f'tolerance = {tolerance!r}: must be finite, >= 0 (0: the '
                             f'configured {self.position} m) and <= {self.largest_request} m')
        return self if tolerance == 0.0 else GoalTolerance(tolerance, self.orientation,
                                                          max(tolerance, self.largest_request))

    def holds(self, position_error: ArrayLike, rotation_error: ArrayLike) -> bool:
        """True when |Δp| ≤ position and |rotation vector| ≤ orientation."""
        return bool(np.linalg.norm(position_error) <= self.position
                    and np.linalg.norm(rotation_error) <= self.orientation)


@dataclass(frozen=True)
class ArrivalSettings:
    """When the drives count as arrived: every encoder within its tolerance of the target and
    slower than its speed; ``timeout`` beyond the trajectory's duration. Then when they stand
    still: every encoder within its ``settle_*`` tolerance of the target for ``settle_window``
    (:class:`~positioning_cell.motion.rest.RestWatch`) ends the settle dwell before
    ``settle_time``."""

    length_tolerance: float = setting(5e-6, 'encoder arrival tolerance, legs', 'm', low=0.0,
                                      high=0.01, dynamic=True)
    theta_tolerance: float = setting(5e-5, 'encoder arrival tolerance, theta', 'rad',
                                     low=0.0, high=0.1, dynamic=True)
    length_speed: float = setting(2e-4, 'at rest below this speed, legs', 'm/s', low=0.0,
                                  high=1.0, dynamic=True)
    theta_speed: float = setting(2e-3, 'at rest below this speed, theta', 'rad/s', low=0.0,
                                 high=1.0, dynamic=True)
    timeout: float = setting(5.0, 'extra time to arrive after the trajectory ends', 's',
                             low=0.1, high=120.0, dynamic=True)
    settle_length: float = setting(
        1.5e-6, 'the settle dwell ends early once every leg encoder has stayed this close to '
        'its target for settle_window', 'm', low=0.0, high=0.01, dynamic=True)
    settle_theta: float = setting(1e-5, '... and every theta encoder this close', 'rad',
                                  low=0.0, high=0.1, dynamic=True)
    settle_window: float = setting(
        0.05, '... for this long (at least the tracker\'s latency; 0: never early, the whole '
        'settle_time)', 's', low=0.0, high=10.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def settle_tolerance(self) -> FloatArray:
        """How close (6,) m, rad every encoder must stay to its target for ``settle_window``
        to end the settle dwell early."""
        return np.array([self.settle_length] * 3 + [self.settle_theta] * 3)

    @property
    def position_tolerance(self) -> FloatArray:
        """Arrival tolerance (6,) m, rad."""
        return np.array([self.length_tolerance] * 3 + [self.theta_tolerance] * 3)

    @property
    def speed_tolerance(self) -> FloatArray:
        """At-rest speed (6,) m/s, rad/s."""
        return np.array([self.length_speed] * 3 + [self.theta_speed] * 3)


@dataclass(frozen=True)
class TrajectorySettings:
    """The ``trajectory:`` block."""

    period: float = setting(0.01, 'spacing of the trajectory points', 's', low=0.001,
                            high=0.5, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class LivenessSettings:
    """How quickly the positioner notices a silent, frozen or refusing world."""

    joint_silence: float = setting(0.2, 'no /legs/joint_states for this long: the leg driver is '
                                   'not responding', 's', low=0.01, high=10.0, dynamic=True)
    answer_timeout: float = setting(0.5, 'the leg driver must accept or refuse a trajectory '
                                    'within this', 's', low=0.01, high=10.0, dynamic=True)
    freeze_window: float = setting(0.5, 'an encoder that does not change for this long while '
                                   'its axis is commanded to move is frozen', 's', low=0.05,
                                   high=10.0, dynamic=True)
    freeze_motion: float = setting(20.0, 'commanded motion in the freeze window above which an '
                                   'unchanged encoder counts as frozen, in encoder counts',
                                   low=1.0, high=1e6, dynamic=True)
    tracker_silence: float = setting(0.5, 'no /metrology/pose for this long while measuring: '
                                     'the tracker is not responding', 's', low=0.05,
                                     high=60.0, dynamic=True)
    scatter_limit: float = setting(6.0, 'tracker readings averaged for a correction may '
                                   'scatter at most this many times their stated sigma',
                                   low=1.0, high=1000.0, dynamic=True)
    homing_timeout: float = setting(120.0, 'referencing must complete within this', 's',
                                    low=1.0, high=3600.0, dynamic=True)
    discovery_timeout: float = setting(
        5.0, 'a command waits at most this long for inputs never seen yet (the first joint '
        "state, the driver's status, the driver matched both ways): a positioner started or "
        'restarted beside a running driver works on its first command', 's', low=0.0,
        high=60.0, dynamic=True)
    heartbeat_period: float = setting(
        0.05, 'period of the heartbeat to the leg driver (/positioner/heartbeat), which stops '
        "a move when it falls silent (leg_driver's command.heartbeat_timeout)", 's', low=0.005,
        high=1.0)
    linear_count: float = setting(1e-6, 'one linear encoder count, for the freeze rule', 'm',
                                  low=1e-9, high=1e-3)
    rotary_count: float = setting(6e-6, 'one rotary encoder count, for the freeze rule',
                                  'rad', low=1e-9, high=1e-2)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class InputSources:
    """The nodes the positioner takes its inputs from (``sources:``, fully qualified names):
    encoder readings and trajectory answers from the leg driver, poses from the tracker.
    Messages of any other node on those topics are ignored and reported."""

    leg_driver: str = setting('/' + NODE_DRIVER, 'the node whose /legs/joint_states and '
                              '/legs/trajectory_status are taken')
    tracker: str = setting('/' + NODE_MEASUREMENT, 'the node whose /metrology/pose is taken')

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ('leg_driver', 'tracker'):
            if not getattr(self, name).startswith('/'):
                raise ParameterError(name, getattr(self, name),
                                     "a fully qualified node name ('/leg_driver', '/ns/node')")


@dataclass(frozen=True)
class OperatorSettings:
    """The operator's surface (``operator:``, read at start; SetCoordinateSystems, SetLimits
    and SetSpeed change what is in force at run time): where the coordinate systems persist,
    the three limit layers, the factory's speed maxima and the jog."""

    coordinate_systems_file: str = setting(
        '', 'YAML file of the user and object coordinate systems (SetCoordinateSystems writes '
        'it; they survive a restart); empty: $ROS_HOME/positioning_cell/coordinate_systems.yaml')
    factory_box: FactoryBoxSettings = group(FactoryBoxSettings, 'the factory box (machine CS)')
    machine_lower: tuple[float, ...] | None = setting(
        None, 'machine-CS box at start, lower bounds Tx, Ty, Tz, Rx, Ry, Rz; not given: the '
        'factory box', 'm, rad', length=6)
    machine_upper: tuple[float, ...] | None = setting(
        None, 'machine-CS box at start, upper bounds', 'm, rad', length=6)
    user_lower: tuple[float, ...] | None = setting(
        None, 'user-CS box at start, lower bounds Tx, Ty, Tz, Rx, Ry, Rz; not given: no user '
        'limit', 'm, rad', length=6)
    user_upper: tuple[float, ...] | None = setting(
        None, 'user-CS box at start, upper bounds', 'm, rad', length=6)
    max_linear_speed: float = setting(0.05, 'factory maximum of the linear speed', 'm/s',
                                      low=1e-5, high=1.0)
    max_angular_speed: float = setting(0.5, 'factory maximum of the angular speed', 'rad/s',
                                       low=1e-5, high=10.0)
    max_linear_acceleration: float = setting(0.2, 'factory maximum of the linear '
                                             'acceleration', 'm/s^2', low=1e-5, high=10.0)
    max_angular_acceleration: float = setting(2.0, 'factory maximum of the angular '
                                              'acceleration', 'rad/s^2', low=1e-5, high=100.0)
    jog_largest_length_step: float = setting(0.005, 'largest jog step of a leg length', 'm',
                                             low=0.0, low_open=True, high=0.1)
    jog_largest_theta_step: float = setting(0.05, 'largest jog step of a theta angle', 'rad',
                                            low=0.0, low_open=True, high=1.0)
    jog_length_speed: float = setting(0.002, 'jog speed of a leg length', 'm/s', low=1e-6,
                                      high=0.1)
    jog_theta_speed: float = setting(0.02, 'jog speed of a theta angle', 'rad/s', low=1e-6,
                                     high=1.0)
    jog_length_acceleration: float = setting(0.01, 'jog acceleration of a leg length',
                                             'm/s^2', low=1e-6, high=1.0)
    jog_theta_acceleration: float = setting(0.1, 'jog acceleration of a theta angle',
                                            'rad/s^2', low=1e-6, high=10.0)
    axis_ranges: AxisRangeSettings = group(
        AxisRangeSettings, 'the live axis ranges (/positioner/axis_ranges, CheckPose)')

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ('machine', 'user'):
            low, high = getattr(self, f'{name}_lower'), getattr(self, f'{name}_upper')
            if (low is None) != (high is None):
                raise ParameterError(f'{name}_lower', low, f'give both {name}_lower and '
                                     f'{name}_upper, or neither')


@dataclass(frozen=True)
class PositionerSettings:
    """Every parameter of the ``positioner`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the machine')
    payload: Payload = group(Payload, 'what the platform carries (load-driven clearance)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine')
    compensation: CompensationSettings = group(CompensationSettings, 'compensation')
    goal_tolerance: GoalTolerance = group(GoalTolerance, 'settle tolerance of a move')
    motion: MotionLimits = group(MotionLimits, 'Cartesian limits of a move')
    trajectory: TrajectorySettings = group(TrajectorySettings, 'the joint trajectories')
    arrival: ArrivalSettings = group(ArrivalSettings, 'arrival of the drives')
    liveness: LivenessSettings = group(LivenessSettings, 'silent, frozen or refusing inputs')
    standstill: StandstillSettings = group(StandstillSettings, 'motion while nothing is '
                                           'commanded')
    sources: InputSources = group(InputSources, 'the nodes the inputs are taken from')
    operator: OperatorSettings = group(OperatorSettings, "the operator's surface: coordinate "
                                       'systems, limit layers, speed maxima, jog')
    settle_time: float = setting(0.2, 'longest dwell after arrival before the pose counts as '
                                 'settled (it ends earlier once the encoders stand still: '
                                 'arrival.settle_*)', 's', low=0.0, high=10.0, dynamic=True)
    measurement_timeout: float = setting(5.0, 'wait for tracker samples', 's', low=0.1,
                                         high=60.0, dynamic=True)
    pose_rate_hz: float = setting(50.0, 'rate of the pose estimate on /positioner/pose', 'Hz',
                                  low=1.0, high=200.0)
    markers_every: int = setting(5, 'the markers, /joint_states and /tf are published with '
                                 'every this many pose estimates', low=1, high=1000)

    def __post_init__(self) -> None:
        check_fields(self)
        op = self.operator
        for name, maximum in (('linear_speed', op.max_linear_speed),
                              ('angular_speed', op.max_angular_speed),
                              ('linear_acceleration', op.max_linear_acceleration),
                              ('angular_acceleration', op.max_angular_acceleration)):
            value = getattr(self.motion, name)
            if value > maximum:
                raise ParameterError(f'motion.{name}', value,
                                     f'above the factory maximum operator.max_{name} = {maximum}')

    @property
    def mode(self) -> CompensationMode:
        """The compensation mode."""
        return CompensationMode(self.compensation.mode)

    def clearance_model(self) -> ClearanceModel:
        """The compensation's clearance model (ConfigError naming a bad key)."""
        return build(self.compensation.clearance, self.mechanism, self.payload, self.structure)


#: The positioner's parameters that other programs read or set (the tools, the calibrator):
#: its compensation mode, the carry distance and the calibration file it loads
#: (:class:`CompensationSettings`).
COMPENSATION_MODE = 'compensation.mode'
CARRY_DISTANCE = 'compensation.carry_distance'
CALIBRATION_FILE = 'compensation.calibration_file'


def machine_settings(config: str | Path, more: Mapping[str, Any] | None = None
                     ) -> PositionerSettings:
    """The positioner's settings in a parameter file (with ``more``, nested parameters, laid
    over them: e.g. a coordinated cell's set's own payload) without its compensation block:
    the nominal machine, payload, structure and motion a tool needs to calibrate it or predict
    its accuracy (a compensation block naming a calibration file is not loaded)."""
    params = merged(node_parameters(load_parameter_file(config), NODE_POSITIONER), more or {})
    params.pop('compensation', None)
    return parse(PositionerSettings, params)
