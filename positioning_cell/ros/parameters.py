"""A node's parameters from the library's settings type: declared with descriptors (range,
read-only flag, constraints text) from the one declaration in the library
(:mod:`positioning_cell.parameters`), parsed into the settings value at start, and every later
set validated by the same parse: a bad value is refused with the library's reason and nothing
changes."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any, Generic, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterValue,
    SetParametersResult,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python

from positioning_cell.errors import ConfigError
from positioning_cell.files import shorten
from positioning_cell.parameters import Declaration, Kind, block, declarations, parse

T = TypeVar('T')

_TYPES = {Kind.FLOAT: Parameter.Type.DOUBLE, Kind.INT: Parameter.Type.INTEGER,
          Kind.BOOL: Parameter.Type.BOOL, Kind.STR: Parameter.Type.STRING,
          Kind.FLOATS: Parameter.Type.DOUBLE_ARRAY, Kind.STRS: Parameter.Type.STRING_ARRAY}
_INT64 = (-(2**63), 2**63 - 1)


def descriptor(declaration: Declaration) -> ParameterDescriptor:
    """The ParameterDescriptor rclpy enforces for ``declaration``: its range (double and
    integer), read-only flag, description and constraints."""
    rule = declaration.rule
    text = rule.description + (f', {rule.unit}' if rule.unit else '')
    desc = ParameterDescriptor(name=declaration.name, description=text,
                               read_only=declaration.read_only,
                               additional_constraints=declaration.constraints())
    if rule.low is not None or rule.high is not None:
        if declaration.kind is Kind.FLOAT:
            desc.floating_point_range = [FloatingPointRange(
                from_value=-sys.float_info.max if rule.low is None else float(rule.low),
                to_value=sys.float_info.max if rule.high is None else float(rule.high),
                step=0.0)]
        elif declaration.kind is Kind.INT:
            desc.integer_range = [IntegerRange(
                from_value=_INT64[0] if rule.low is None else int(rule.low),
                to_value=_INT64[1] if rule.high is None else int(rule.high), step=0)]
    return desc


def plain(value: Any) -> Any:
    """A parameter value as plain Python (rclpy gives arrays as array.array)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return list(value)


def requested_names(cls: type, prefix: str) -> list[str]:
    """The parameter names of settings type ``cls`` under ``prefix`` (``'mechanism.'``): what a
    GetParameters request for them lists, in :func:`parse_answer`'s order."""
    return [d.name for d in declarations(cls, prefix)]


def parse_answer(cls: type[T], prefix: str, values: Sequence[ParameterValue]) -> T:
    """Settings of type ``cls`` from another node's GetParameters answer ``values`` to
    :func:`requested_names` (ConfigError names a value that does not parse)."""
    names = requested_names(cls, prefix)
    flat = {n: plain(parameter_value_to_python(v)) for n, v in zip(names, values, strict=False)}
    return parse(cls, block(flat, prefix.rstrip('.')), prefix)


def _value(node: Node, name: str) -> Any:
    """The plain value of a declared parameter; None while it is declared without one."""
    try:
        return plain(node.get_parameter(name).value)
    except ParameterUninitializedException:
        return None


class NodeParameters(Generic[T]):
    """Every parameter of settings type ``cls`` declared on ``node``; :attr:`settings` the
    parsed value (ConfigError at start names the bad key); ``check(settings, names)`` may refuse
    a set by raising ConfigError (what parsing alone cannot judge, e.g. a file's content);
    ``on_change(settings, names)`` runs after each accepted set, with the names that were
    set."""

    def __init__(self, node: Node, cls: type[T],
                 on_change: Callable[[T, frozenset[str]], None] | None = None,
                 check: Callable[[T, frozenset[str]], None] | None = None) -> None:
        self._cls = cls
        self._on_change = on_change
        self._check = check
        self._declared = {d.name: d for d in declarations(cls)}
        for d in self._declared.values():
            # None and [] cannot be declared as values: the parameter is declared by its type
            # (unset until given), which the parse reads as the default.
            default = _TYPES[d.kind] if d.default in (None, []) else d.default
            node.declare_parameter(d.name, default, descriptor(d))
        self.values = {n: _value(node, n) for n in self._declared}
        self.settings: T = parse(cls, self.values)
        node.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        candidate = dict(self.values)
        for p in params:
            if p.name in self._declared:
                candidate[p.name] = plain(p.value)
        names = frozenset(p.name for p in params)
        try:
            settings = parse(self._cls, candidate)
            if self._check is not None:
                self._check(settings, names)
        except ConfigError as err:  # the reason in a few hundred characters at most
            return SetParametersResult(successful=False, reason=shorten(str(err)))
        self.values, self.settings = candidate, settings
        if self._on_change is not None:
            self._on_change(settings, names)
        return SetParametersResult(successful=True)
