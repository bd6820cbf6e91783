"""Parameters declared once (positioning_cell.parameters): declarations, parsing of nested and
dotted blocks, groups keeping the defaults their parent gives them, validation on direct
construction (the ROS descriptors made from the same declaration: test_ros_parameters)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from positioning_cell.errors import ConfigError
from positioning_cell.parameters import (
    Kind,
    ParameterError,
    check_fields,
    declarations,
    group,
    parse,
    setting,
    to_params,
)


@dataclass(frozen=True)
class Inner:
    speed: float = setting(1.0, 'a speed', 'm/s', low=0.0, low_open=True, high=5.0,
                           dynamic=True)
    count: int = setting(3, 'a count', low=1, high=10)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Outer:
    name: str = setting('a', 'a choice', choices=('a', 'b'))
    offsets: tuple[tuple[float, float, float], ...] = setting(((0.0, 0.0, 0.0),) * 2,
                                                               'rows', 'm', length=6)
    optional: float | None = setting(None, 'unset unless given', 's', low=0.0)
    flag: bool = setting(False, 'a flag')
    words: tuple[str, ...] = setting((), 'some words')
    first: Inner = group(Inner, 'the first group')
    second: Inner = group(Inner, 'the second, with its own defaults',
                          default=lambda: Inner(speed=2.0))

    def __post_init__(self) -> None:
        check_fields(self)


def test_declarations_expand_groups_with_their_parents_defaults() -> None:
    decl = {d.name: d for d in declarations(Outer, 'x.')}
    assert list(decl) == ['x.name', 'x.offsets', 'x.optional', 'x.flag', 'x.words',
                          'x.first.speed', 'x.first.count', 'x.second.speed', 'x.second.count']
    assert decl['x.offsets'].kind is Kind.FLOATS and decl['x.offsets'].default == [0.0] * 6
    assert decl['x.optional'].default is None and decl['x.words'].default == []
    assert decl['x.first.speed'].default == 1.0 and decl['x.second.speed'].default == 2.0
    assert decl['x.first.count'].kind is Kind.INT and decl['x.flag'].kind is Kind.BOOL
    assert not decl['x.first.speed'].read_only and decl['x.name'].read_only


def test_parse_nested_and_dotted_alike() -> None:
    nested = parse(Outer, {'second': {'count': 4}, 'offsets': [1, 2, 3, 4, 5, 6]})
    dotted = parse(Outer, {'second.count': 4, 'offsets': [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]})
    assert nested == dotted
    assert nested.offsets == ((1.0, 2.0, 3.0), (4.0, 5.0, 6.0))
    assert nested.second == Inner(speed=2.0, count=4)  # the group's own default kept
    assert parse(Outer, {'optional': None}).optional is None  # unset: the default
    assert parse(Outer, to_params(nested)) == nested


@pytest.mark.parametrize(('params', 'message'), [
    ({'nmae': 'a'}, 'x.nmae: unknown parameter'),
    ({'name': 'c'}, "x.name = 'c': expected one of a, b"),
    ({'first.speed': 0.0}, 'x.first.speed = 0.0: must be in (0, 5] m/s'),
    ({'first.speed': math.nan}, 'x.first.speed = nan: must be finite'),
    ({'first.count': 2.5}, 'x.first.count = 2.5: expected an integer'),
    ({'first.count': 11}, 'x.first.count = 11: must be in [1, 10]'),
    ({'flag': 1}, 'x.flag = 1: expected true or false'),
    ({'offsets': [1.0] * 5}, 'x.offsets = [1.0, 1.0, 1.0, 1.0, 1.0]: expected 6 numbers'),
    ({'optional': -1.0}, 'x.optional = -1.0: must be >= 0 s'),
    ({'words': 'one'}, "x.words = 'one': expected a list"),
])
def test_bad_values_name_the_key(params: dict[str, object], message: str) -> None:
    with pytest.raises(ParameterError) as info:
        parse(Outer, params, 'x.')
    assert str(info.value) == message


def test_direct_construction_is_held_to_the_same_rules() -> None:
    with pytest.raises(ConfigError, match=r'speed = -1.0: must be in \(0, 5\] m/s'):
        Inner(speed=-1.0)
    assert Inner(speed=2).speed == 2.0 and isinstance(Inner(speed=2).speed, float)
