"""Parameters declared once.

Every settings value type of the library is a frozen dataclass whose fields are made with
:func:`setting`: default, description, unit, range or choices, array length, and whether it may
change while a node runs. From that single declaration come

- the library's validation: ``__post_init__`` calls :func:`check_fields`, so a value built in
  Python is held to the same rules as one read from a file;
- parsing of parameter blocks, nested (a YAML file) or dotted (what rclpy gives): :func:`parse`;
- a node's ROS declarations (:func:`declarations`): dotted name, default, type, rule, which
  ``positioning_cell.ros.parameters`` turns into ParameterDescriptors (double and integer
  ranges, read-only flag, constraints text).

A field whose type is itself such a dataclass is a group: its fields appear under the field's
name (``motion.linear_speed``). Arrays are tuples of floats or strings (ROS parameters are flat
lists; a nested tuple such as 3 × 3 offsets is given as 9 numbers, row-major). A field typed
``X | None`` defaults to None: declared without a value, "not given".
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import MISSING, Field, dataclass, field, fields, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from positioning_cell.config import flatten, load_parameter_file
from positioning_cell.errors import ConfigError

T = TypeVar('T')

#: Key of a field's :class:`Rule` in its dataclass metadata.
RULE = 'positioning_cell.rule'


#: The ``value`` of a ParameterError about a key rather than a value (an unknown key).
NO_VALUE: Any = object()


class ParameterError(ConfigError):
    """One parameter is out of its rule: ``name`` (dotted, relative to the value type it belongs
    to until :func:`parse` prefixes the group), the ``value`` (or :data:`NO_VALUE`) and
    ``why``."""

    def __init__(self, name: str, value: Any, why: str) -> None:
        super().__init__(f'{name}: {why}' if value is NO_VALUE else f'{name} = {value!r}: {why}')
        self.name, self.value, self.why = name, value, why

    def within(self, prefix: str) -> ParameterError:
        """The same error with ``prefix`` (a group's dotted path and '.') before the name."""
        return ParameterError(prefix + self.name, self.value, self.why)


class Kind(Enum):
    """ROS parameter type of a declaration."""

    FLOAT = 'double'
    INT = 'integer'
    BOOL = 'bool'
    STR = 'string'
    FLOATS = 'double_array'
    STRS = 'string_array'


@dataclass(frozen=True)
class Rule:
    """What a parameter may be. ``low`` / ``high``: inclusive bounds, strict with ``low_open`` /
    ``high_open``; ``choices``: allowed strings; ``length``: allowed element counts of an
    array (flattened); ``finite``: NaN and ±inf refused (``False`` lets +inf through, e.g. a
    rigid stiffness); ``dynamic``: may be set while the node runs (else read-only);
    ``convert``: applied to a given value before the checks (e.g. 3 principal moments → 3 × 3)."""

    description: str
    unit: str = ''
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] | None = None
    length: tuple[int, ...] | None = None
    finite: bool = True
    dynamic: bool = False
    convert: Callable[[Any], Any] | None = None

    def bounds_text(self, *, unit: bool = True) -> str:
        """The range in words, e.g. '> 0 m/s' or 'in [0, 1]' (without the unit if not
        ``unit``)."""
        unit_text = f' {self.unit}' if self.unit and unit else ''
        low = None if self.low is None else f'{"> " if self.low_open else ">= "}{self.low:g}'
        high = None if self.high is None else f'{"< " if self.high_open else "<= "}{self.high:g}'
        if low and high:
            left, right = '(' if self.low_open else '[', ')' if self.high_open else ']'
            return f'in {left}{self.low:g}, {self.high:g}{right}{unit_text}'
        return f'{low or high}{unit_text}' if (low or high) else ''

    def check_number(self, name: str, value: float | int) -> None:
        """Raise ParameterError when ``value`` breaks the range or finiteness."""
        if math.isnan(value) or (self.finite and math.isinf(value)) or value == -math.inf:
            raise ParameterError(name, value, 'must be finite' if self.finite else
                                 'must be a number (NaN and -inf refused)')
        too_low = self.low is not None and (value <= self.low if self.low_open
                                            else value < self.low)
        too_high = self.high is not None and (value >= self.high if self.high_open
                                              else value > self.high)
        if too_low or too_high:
            raise ParameterError(name, value, f'must be {self.bounds_text()}')


def setting(default: Any = MISSING, description: str = '', unit: str = '', *,
            default_factory: Callable[[], Any] | Any = MISSING, low: float | None = None,
            high: float | None = None, low_open: bool = False, high_open: bool = False,
            choices: Sequence[str] | None = None, length: Sequence[int] | int | None = None,
            finite: bool = True, dynamic: bool = False,
            convert: Callable[[Any], Any] | None = None) -> Any:
    """A dataclass field declared as a parameter (see :class:`Rule`)."""
    rule = Rule(description, unit, low, high, low_open, high_open,
                tuple(choices) if choices is not None else None,
                (length,) if isinstance(length, int) else (tuple(length) if length else None),
                finite, dynamic, convert)
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata={RULE: rule})
    return field(default=default, metadata={RULE: rule})


def group(cls: type[T], description: str = '', *,
          default: Callable[[], T] | None = None) -> Any:
    """A dataclass field holding a nested settings type, by default ``cls()`` (or what
    ``default()`` makes)."""
    return field(default_factory=default or cls, metadata={RULE: Rule(description)})


# -- the declarations of a value type -----------------------------------------------------------
@dataclass(frozen=True)
class Declaration:
    """One parameter: dotted ``name``, ROS ``kind``, ``default`` as a ROS value (float, int,
    bool, str, list of floats or strings; None: declared without a value) and its ``rule``."""

    name: str
    kind: Kind
    default: Any
    rule: Rule

    @property
    def read_only(self) -> bool:
        """True unless the rule says it may change while the node runs."""
        return not self.rule.dynamic

    def constraints(self) -> str:
        """Unit, range, choices and length in words (a ParameterDescriptor's
        additional_constraints)."""
        parts = []
        if self.rule.unit:
            parts.append(f'unit: {self.rule.unit}')
        if self.rule.low is not None or self.rule.high is not None:
            parts.append(self.rule.bounds_text(unit=False))
        if self.rule.choices:
            parts.append('one of: ' + ', '.join(self.rule.choices))
        if self.rule.length:
            parts.append('values: ' + ' or '.join(str(n) for n in self.rule.length))
        return '; '.join(parts)


@dataclass(frozen=True)
class _FieldType:
    kind: Kind | None  # None: a group
    optional: bool
    shape: tuple[int | None, ...]  # array shape (flattened for ROS); () for scalars
    group: type | None = None


def _field_type(annotation: Any) -> _FieldType:
    """The parameter kind of a resolved field annotation."""
    optional = False
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(members) != 1:
            raise TypeError(f'unsupported parameter type {annotation!r}')
        annotation, optional = members[0], True
        origin = typing.get_origin(annotation)
    if is_dataclass(annotation):
        return _FieldType(None, optional, (), annotation)  # type: ignore[arg-type]
    scalars = {float: Kind.FLOAT, int: Kind.INT, bool: Kind.BOOL, str: Kind.STR}
    if annotation in scalars:
        return _FieldType(scalars[annotation], optional, ())
    if origin is tuple:
        args = typing.get_args(annotation)
        inner = args[0]
        count: int | None = None if (len(args) == 2 and args[1] is Ellipsis) else len(args)
        if inner is str:
            return _FieldType(Kind.STRS, optional, (count,))
        if inner is float:
            return _FieldType(Kind.FLOATS, optional, (count,))
        nested = _field_type(inner)
        if nested.kind is Kind.FLOATS:
            return _FieldType(Kind.FLOATS, optional, (count, *nested.shape))
    raise TypeError(f'unsupported parameter type {annotation!r}')


_FIELDS: dict[type, tuple[tuple[Field[Any], Rule, _FieldType], ...]] = {}


def _fields(cls: type) -> tuple[tuple[Field[Any], Rule, _FieldType], ...]:
    """Each field of settings type ``cls`` with its rule and parameter kind (computed once)."""
    known = _FIELDS.get(cls)
    if known is not None:
        return known
    hints = typing.get_type_hints(cls)
    out = []
    for f in fields(cls):
        rule = f.metadata.get(RULE)
        if rule is None:
            raise TypeError(f'{cls.__name__}.{f.name} is not declared with setting() or group()')
        out.append((f, rule, _field_type(hints[f.name])))
    _FIELDS[cls] = tuple(out)
    return _FIELDS[cls]


def _default(f: Field[Any]) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def _ros_value(value: Any, kind: Kind) -> Any:
    if value is None:
        return None
    if kind is Kind.FLOATS:
        return [float(v) for v in np.asarray(value, dtype=float).ravel()]
    if kind is Kind.STRS:
        return [str(v) for v in value]
    return value


def declarations(cls: type, prefix: str = '', defaults: Any = None) -> list[Declaration]:
    """Every parameter of settings type ``cls``, groups expanded, names prefixed; the defaults
    are those of ``defaults`` (an instance; default: each field's own default), so a group
    keeps the defaults its parent gives it."""
    out: list[Declaration] = []
    for f, rule, ftype in _fields(cls):
        name = prefix + f.name
        default = _default(f) if defaults is None else getattr(defaults, f.name)
        if default is MISSING:
            raise TypeError(f'{cls.__name__}.{f.name} has no default')
        if ftype.kind is None:
            assert ftype.group is not None
            out += declarations(ftype.group, name + '.', default)
            continue
        out.append(Declaration(name, ftype.kind, _ros_value(default, ftype.kind), rule))
    return out


# -- checking and parsing -----------------------------------------------------------------------
def _number(name: str, value: Any, integer: bool) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(name, value,
                             'expected an integer' if integer else 'expected a number')
    if integer:
        if isinstance(value, (float, np.floating)) and not float(value).is_integer():
            raise ParameterError(name, value, 'expected an integer')
        return int(value)
    return float(value)


def _array(name: str, value: Any, ftype: _FieldType, rule: Rule) -> Any:
    if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
        raise ParameterError(name, value, 'expected a list')
    if ftype.kind is Kind.STRS:
        if not all(isinstance(v, str) for v in value):
            raise ParameterError(name, value, 'expected a list of strings')
        return tuple(value)
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError) as err:
        raise ParameterError(name, value, 'expected a list of numbers') from err
    shape = ftype.shape
    fixed = [d for d in shape if d is not None]
    allowed = rule.length
    if allowed is None and None not in shape:
        allowed = (math.prod(fixed),)
    if allowed is not None and arr.size not in allowed:
        raise ParameterError(name, list(value), f'expected {" or ".join(map(str, allowed))} '
                                               'numbers')
    if None in shape[1:] or (len(shape) > 1 and arr.size % math.prod(fixed)):
        raise ParameterError(name, list(value), f'expected rows of {math.prod(fixed)} numbers')
    for v in arr:
        rule.check_number(name, float(v))
    if len(shape) == 1:
        return tuple(float(v) for v in arr)
    rows = arr.reshape(-1, *shape[1:])
    return tuple(tuple(float(x) for x in row) for row in rows)


def coerce(name: str, value: Any, rule: Rule, ftype: _FieldType) -> Any:
    """``value`` as the field's Python type, checked against ``rule`` (ParameterError)."""
    if value is None:
        if ftype.optional:
            return None
        raise ParameterError(name, value, 'a value is required')
    if rule.convert is not None:
        value = rule.convert(value)
    kind = ftype.kind
    if kind in (Kind.FLOAT, Kind.INT):
        number = _number(name, value, kind is Kind.INT)
        rule.check_number(name, number)
        return number
    if kind is Kind.BOOL:
        if not isinstance(value, (bool, np.bool_)):
            raise ParameterError(name, value, 'expected true or false')
        return bool(value)
    if kind is Kind.STR:
        if not isinstance(value, str):
            raise ParameterError(name, value, 'expected a string')
        if rule.choices is not None and value not in rule.choices:
            raise ParameterError(name, value, 'expected one of ' + ', '.join(rule.choices))
        return value
    return _array(name, value, ftype, rule)


def check_fields(obj: Any) -> None:
    """Hold every field of the settings value ``obj`` to its rule (ParameterError naming the
    field) and store the coerced value (floats as float, arrays as tuples); call from
    ``__post_init__``."""
    for f, rule, ftype in _fields(type(obj)):
        value = getattr(obj, f.name)
        if ftype.kind is None:
            if value is None and ftype.optional:
                continue
            if not isinstance(value, ftype.group):  # type: ignore[arg-type]
                raise ParameterError(f.name, value, f'expected a {ftype.group.__name__}'  # type: ignore[union-attr]
                                     )
            continue
        coerced = coerce(f.name, value, rule, ftype)
        if coerced is not value:
            object.__setattr__(obj, f.name, coerced)


def block(params: Mapping[str, Any], prefix: str) -> dict[str, Any]:
    """The parameters under ``prefix`` (nested ``{prefix: {...}}`` or dotted ``prefix.key``),
    as dotted keys relative to it; all of them for an empty ``prefix``."""
    flat = flatten(params)
    if not prefix:
        return flat
    start = prefix + '.'
    return {k[len(start):]: v for k, v in flat.items() if k.startswith(start)}


def parse(cls: type[T], params: Mapping[str, Any], prefix: str = '') -> T:
    """A ``cls`` from parameters (nested or dotted keys relative to it; missing or None values
    keep the defaults). An unknown key or a value out of its rule raises ParameterError naming
    the dotted key, after ``prefix`` (the block's own name and '.', for the message)."""
    flat = flatten(params)
    known = {d.name for d in declarations(cls)}
    unknown = sorted(set(flat) - known)
    if unknown:
        raise ParameterError(prefix + unknown[0], NO_VALUE,
                             'unknown parameter' + (f' (and {", ".join(unknown[1:])})'
                                                    if unknown[1:] else ''))
    try:
        return _build(cls, flat, '')
    except ParameterError as err:
        raise err.within(prefix) from None



def parse_block(cls: type[T], path: str | Path, name: str) -> T:
    """The ``name:`` block of the YAML file at ``path`` (a program file's ``production:``,
    ``acceptance:``) as a ``cls`` (:func:`parse`; a file without the block: the defaults).
    ConfigError naming the file and the key for a block that is not a mapping or a bad
    value."""
    block = load_parameter_file(path).get(name) or {}
    if not isinstance(block, Mapping):
        raise ConfigError(f'{path}: {name}: expected a mapping')
    try:
        return parse(cls, block, f'{name}.')
    except ValueError as err:  # ParameterError is one
        raise ConfigError(f'{path}: {err}') from err

def _build(cls: type[T], flat: Mapping[str, Any], path: str, base: Any = None) -> T:
    """A ``cls`` from the dotted values under ``path``; the values not given are those of
    ``base`` (the default the parent gives this group), else the field defaults."""
    kwargs: dict[str, Any] = {}
    for f, rule, ftype in _fields(cls):
        key = path + f.name
        if ftype.kind is None:
            assert ftype.group is not None
            if any(k.startswith(key + '.') for k in flat):
                default = _default(f) if base is None else getattr(base, f.name)
                kwargs[f.name] = _build(ftype.group, flat, key + '.', default)
            continue
        value = flat.get(key)
        if value is not None:
            kwargs[f.name] = coerce(key, value, rule, ftype)
    try:
        return cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)
    except ParameterError as err:
        raise err.within(path) from None


def to_params(obj: Any) -> dict[str, Any]:
    """The nested parameter block of a settings value (inverse of :func:`parse`; arrays as
    flat lists, unset values left out)."""
    out: dict[str, Any] = {}
    for f, _, ftype in _fields(type(obj)):
        value = getattr(obj, f.name)
        if ftype.kind is None:
            out[f.name] = to_params(value)
        elif value is not None:
            out[f.name] = _ros_value(value, ftype.kind)
    return out

