"""Plumbing shared by the cell's nodes: QoS profiles, the main() idiom, declared and validated
parameters, and message <-> numpy conversions. No mathematics lives here."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseStamped, Vector3Stamped
from numpy.typing import ArrayLike
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanism import Mechanism

# QoS chosen on purpose: everything the cell records is reliable (a recorder must lose
# nothing), commands are reliable, the current goal is latched for late joiners.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

BASE_FRAME = 'base'


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None,
        *, threads: int = 4) -> int:
    """The Jazzy main() idiom: init, spin until Ctrl-C / SIGTERM / shutdown, clean up.

    A multi-threaded executor, so a service callback can wait for topic data. Invalid
    parameters at start: the reason on stderr and exit code 2.
    """
    rclpy.init(args=list(args) if args is not None else None)
    node: Node | None = None
    try:
        node = node_factory()
        executor = MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as err:
        print(f'invalid parameters: {err}', file=sys.stderr)
        return 2
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- parameters ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ParamSpec:
    """A declared parameter: default (its type is the parameter's type), description, an
    optional inclusive range for numbers, allowed values for strings, read-only flag."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False

    def descriptor(self) -> ParameterDescriptor:
        """The ParameterDescriptor rclpy enforces (range for doubles)."""
        desc = ParameterDescriptor(name=self.name, description=self.description,
                                   read_only=self.read_only)
        if self.choices:
            desc.additional_constraints = 'one of: ' + ', '.join(self.choices)
        if (self.low is not None and self.high is not None and isinstance(self.default, float)):
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return desc

    def check(self, value: Any) -> str | None:
        """None when ``value`` is acceptable, else the reason."""
        if self.choices is not None and value not in self.choices:
            return f'{self.name} = {value!r}: expected one of {", ".join(self.choices)}'
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                return f'{self.name} = {value!r}: must be finite'
            if self.low is not None and value < self.low:
                return f'{self.name} = {value!r}: below the minimum {self.low}'
            if self.high is not None and value > self.high:
                return f'{self.name} = {value!r}: above the maximum {self.high}'
        return None


class Parameters:
    """Declares ``specs`` on a node, validates every later set (range, choices, and an optional
    whole-set validator that may raise ConfigError), and keeps the current values."""

    def __init__(self, node: Node, specs: Iterable[ParamSpec],
                 validate: Callable[[dict[str, Any]], object] | None = None,
                 on_change: Callable[[dict[str, Any]], None] | None = None) -> None:
        self._specs = {s.name: s for s in specs}
        self._validate = validate
        self._on_change = on_change
        self.values: dict[str, Any] = {}
        for spec in self._specs.values():
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
            self.values[spec.name] = param.value
        problem = self._problem(self.values)
        if problem:
            raise ConfigError(problem)
        node.add_on_set_parameters_callback(self._on_set)

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def _problem(self, values: dict[str, Any]) -> str | None:
        for name, value in values.items():
            spec = self._specs.get(name)
            if spec is not None:
                reason = spec.check(value)
                if reason:
                    return reason
        if self._validate is not None:
            try:
                self._validate(values)
            except (ConfigError, InputError) as err:
                return str(err)
        return None

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        candidate = dict(self.values)
        for p in params:
            if p.name in self._specs:
                default = self._specs[p.name].default
                if p.type_ == Parameter.Type.NOT_SET or not _same_kind(default, p.value):
                    return SetParametersResult(
                        successful=False,
                        reason=f'{p.name} = {p.value!r}: expected a {type(default).__name__}')
                candidate[p.name] = p.value
        reason = self._problem(candidate)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        self.values = candidate
        if self._on_change is not None:
            self._on_change(candidate)
        return SetParametersResult(successful=True)


def _same_kind(default: Any, value: Any) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, (list, tuple)):
        return isinstance(value, (list, tuple)) or hasattr(value, 'tolist')
    return isinstance(value, type(default))


def block_specs(prefix: str, defaults: Mapping[str, Any], what: str) -> list[ParamSpec]:
    """Read-only ``prefix.*`` parameters from a value type's ``to_params()`` defaults; nested
    sequences are flattened (row-major), as a ROS parameter array must be."""
    specs = []
    for key, value in defaults.items():
        default = (np.asarray(value, dtype=float).ravel().tolist()
                   if isinstance(value, (list, tuple)) else value)
        specs.append(ParamSpec(f'{prefix}.{key}', default, f'{what}: {key} (SI units)',
                               read_only=True))
    return specs


def mechanism_specs() -> list[ParamSpec]:
    """Read-only ``mechanism.*`` parameters with the seed 000 defaults (config/cell.yaml)."""
    return block_specs('mechanism', Mechanism.default().to_params(),
                       '3-UPS geometry (design/kinematics.md)')


def mechanism_from(values: Mapping[str, Any]) -> Mechanism:
    """The Mechanism in a node's ``mechanism.*`` parameter values (ConfigError if invalid)."""
    return Mechanism.from_params({k: (list(v) if hasattr(v, '__len__') else v)
                                  for k, v in values.items() if k.startswith('mechanism.')})


def flat_block(values: Mapping[str, Any], prefix: str) -> dict[str, Any]:
    """The parameters under ``prefix.`` with the prefix removed (arrays as lists)."""
    start = prefix + '.'
    return {k[len(start):]: (list(v) if isinstance(v, (list, tuple)) or hasattr(v, 'tolist')
                             else v)
            for k, v in values.items() if k.startswith(start)}


# -- conversions -----------------------------------------------------------------------------
def pose_arrays(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) m and quaternion (4,) x, y, z, w of a geometry_msgs/Pose (not validated)."""
    p, o = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.x, o.y, o.z, o.w])


def pose_msg(position: ArrayLike, quaternion: ArrayLike) -> Pose:
    """geometry_msgs/Pose from a position (m) and a quaternion x, y, z, w."""
    msg = Pose()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in np.ravel(position))
    (msg.orientation.x, msg.orientation.y, msg.orientation.z,
     msg.orientation.w) = (float(v) for v in np.ravel(quaternion))
    return msg


def pose_stamped(position: ArrayLike, quaternion: ArrayLike, stamp: Time,
                 frame: str = BASE_FRAME) -> PoseStamped:
    """geometry_msgs/PoseStamped in ``frame``."""
    msg = PoseStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.pose = pose_msg(position, quaternion)
    return msg


def vector3_stamped(vector: ArrayLike, stamp: Time,
                    frame: str = BASE_FRAME) -> Vector3Stamped:
    """geometry_msgs/Vector3Stamped in ``frame``."""
    msg = Vector3Stamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in np.ravel(vector))
    return msg


def joint_state(names: Sequence[str], stamp: Time, position: ArrayLike,
                velocity: ArrayLike = (), effort: ArrayLike = ()) -> JointState:
    """sensor_msgs/JointState (SI: m, rad, m/s, rad/s, N, N·m)."""
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = [float(v) for v in np.ravel(position)]
    msg.velocity = [float(v) for v in np.ravel(velocity)]
    msg.effort = [float(v) for v in np.ravel(effort)]
    return msg


def joint_values(msg: JointState, names: Sequence[str],
                 field: str = 'position') -> np.ndarray | None:
    """The values of ``names`` (in that order) from a JointState field, or None if any is
    missing; JointState may list joints in any order."""
    values = getattr(msg, field)
    index = {n: i for i, n in enumerate(msg.name)}
    if len(values) != len(msg.name) or any(n not in index for n in names):
        return None
    return np.array([values[index[n]] for n in names], dtype=float)


LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
          'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}


def diagnostic(name: str, level: str, message: str, values: Mapping[str, Any],
               stamp: Time, hardware_id: str = 'positioning_cell') -> DiagnosticArray:
    """A DiagnosticArray with one status; ``level`` is ok, warn, error or stale."""
    status = DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                              hardware_id=hardware_id,
                              values=[KeyValue(key=str(k), value=str(v))
                                      for k, v in values.items()])
    array = DiagnosticArray()
    array.header.stamp = stamp
    array.status = [status]
    return array
