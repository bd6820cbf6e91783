"""Affine expressions and quantities of a mechanism file: a vector's length and angle (seed 004
eq. 16: ``a7``, ``45 deg - a8``, ``90 deg - u1``), a scalar loop equation (h_θ), an offset.

An expression is Σ c_k·s_k + k₀: symbols s_k (sources, unknowns, inputs; a derived symbol,
e.g. a gap connector's orientation angle, is replaced by its own expression) with numeric
coefficients, and a constant. Grammar: ``+``, ``-``, ``*`` and ``/`` by a plain number,
parentheses; a number may carry a unit (``45 deg``, ``0.2 rad``, ``85 mm``, ``0.085 m``). A
product of two non-constant factors is refused (not affine).

Dimensions: every term of an expression is a length or every term an angle. A bare number is
a length in the file's length unit (``units.length``: mm or m); an angle constant needs
``deg`` or ``rad`` (a bare 0 is allowed). Inside, everything is SI: metres and radians.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from positioning_cell.errors import ConfigError

LENGTH = 'length'
ANGLE = 'angle'
DIMENSIONS = (LENGTH, ANGLE)
#: Unit → (dimension, SI factor).
UNITS: dict[str, tuple[str, float]] = {
    'mm': (LENGTH, 1e-3), 'm': (LENGTH, 1.0), 'deg': (ANGLE, math.pi / 180.0),
    'rad': (ANGLE, 1.0)}
LENGTH_UNITS = ('mm', 'm')
_TOKEN = re.compile(r'\s*(?:(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)'
                    r'|(?P<name>[^\W\d]\w*)|(?P<op>[-+*/()]))')
_NOT_FINITE = ('nan', 'inf', 'infinity')


@dataclass(frozen=True)
class Affine:
    """Σ coefficient·symbol + ``constant`` (SI: m or rad), of one ``dimension`` (``length`` or
    ``angle``). ``terms`` (symbol, coefficient) in order of first appearance, no zeros."""

    terms: tuple[tuple[str, float], ...]
    constant: float
    dimension: str

    @classmethod
    def zero(cls, dimension: str) -> Affine:
        """0 of ``dimension``."""
        return cls((), 0.0, dimension)

    @classmethod
    def of(cls, name: str, dimension: str, coefficient: float = 1.0) -> Affine:
        """``coefficient``·``name``."""
        return cls(((name, coefficient),), 0.0, dimension)

    @property
    def symbols(self) -> tuple[str, ...]:
        """The symbols with a non-zero coefficient."""
        return tuple(name for name, _ in self.terms)

    def evaluate(self, values: Mapping[str, float]) -> float:
        """The value (SI) with every symbol taken from ``values``."""
        return self.constant + sum(c * values[name] for name, c in self.terms)


@dataclass
class _Partial:
    """An expression while it is parsed: symbol coefficients, the constant of each unit
    dimension (SI) and of bare numbers, and which dimensions appeared."""

    coefs: dict[str, float] = field(default_factory=dict)
    si: float = 0.0
    bare: float = 0.0
    dims: set[str] = field(default_factory=set)
    has_bare: bool = False

    @property
    def pure(self) -> bool:
        """A plain number: no symbol, no unit."""
        return not self.coefs and not self.dims

    def add(self, other: _Partial, sign: float) -> None:
        for k, v in other.coefs.items():
            self.coefs[k] = self.coefs.get(k, 0.0) + sign * v
        self.si += sign * other.si
        self.bare += sign * other.bare
        self.dims |= other.dims
        self.has_bare |= other.has_bare

    def scaled(self, factor: float) -> _Partial:
        return _Partial({k: v * factor for k, v in self.coefs.items()}, self.si * factor,
                        self.bare * factor, set(self.dims), self.has_bare)


#: What a symbol stands for while parsing: its dimension (a base symbol) or its expression
#: (a derived symbol).
SymbolTable = Mapping[str, 'str | Affine']


class _Parser:
    def __init__(self, text: str, symbols: SymbolTable, where: str) -> None:
        self.text, self.symbols, self.where = text, symbols, where
        self.tokens: list[tuple[str, str]] = []
        pos = 0
        stripped = text.rstrip()
        while pos < len(stripped):
            m = _TOKEN.match(stripped, pos)
            if m is None or m.end() == pos:
                self.fail(f'unexpected character {stripped[pos:].lstrip()[:1]!r}')
            assert m is not None
            kind = m.lastgroup or ''
            self.tokens.append((kind, m.group(kind)))
            pos = m.end()
        self.pos = 0

    def fail(self, why: str) -> None:
        raise ConfigError(f'{self.where} = {self.text!r}: {why}')

    def peek(self) -> tuple[str, str]:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else ('end', '')

    def take(self) -> tuple[str, str]:
        token = self.peek()
        self.pos += 1
        return token

    def parse(self) -> _Partial:
        if not self.tokens:
            self.fail('empty expression')
        out = self.sum()
        if self.peek()[0] != 'end':
            self.fail(f'unexpected {self.peek()[1]!r}')
        return out

    def sum(self) -> _Partial:
        out = _Partial()
        sign = 1.0
        if self.peek() in (('op', '+'), ('op', '-')):
            sign = -1.0 if self.take()[1] == '-' else 1.0
        out.add(self.product(), sign)
        while self.peek() in (('op', '+'), ('op', '-')):
            sign = -1.0 if self.take()[1] == '-' else 1.0
            out.add(self.product(), sign)
        return out

    def product(self) -> _Partial:
        out = self.factor()
        while self.peek() in (('op', '*'), ('op', '/')):
            op = self.take()[1]
            right = self.factor()
            if op == '/':
                if not right.pure or right.bare == 0.0:
                    self.fail('division only by a non-zero plain number')
                out = out.scaled(1.0 / right.bare)
            elif right.pure:
                out = out.scaled(right.bare)
            elif out.pure:
                out = right.scaled(out.bare)
            else:
                self.fail('not affine: a product of two terms that are not plain numbers')
        return out

    def factor(self) -> _Partial:
        kind, value = self.take()
        if kind == 'op' and value == '(':
            inner = self.sum()
            if self.take() != ('op', ')'):
                self.fail('missing )')
            return inner
        if kind == 'op' and value == '-':
            return self.factor().scaled(-1.0)
        if kind == 'number':
            number = float(value)
            if self.peek()[0] == 'name' and self.peek()[1] in UNITS:
                dim, factor = UNITS[self.take()[1]]
                return _Partial(si=number * factor, dims={dim})
            return _Partial(bare=number, has_bare=True)
        if kind == 'name':
            return self.symbol(value)
        self.fail(f'unexpected {value!r}' if value else 'unexpected end')
        raise AssertionError  # unreachable: fail raises

    def symbol(self, name: str) -> _Partial:
        if name in UNITS:
            self.fail(f'unit {name!r} without a number before it')
        if name.lower() in _NOT_FINITE:
            self.fail('not a finite number')
        meaning = self.symbols.get(name)
        if meaning is None:
            known = ', '.join(sorted(self.symbols)) or 'none'
            self.fail(f'unknown symbol {name!r} (known: {known})')
        if isinstance(meaning, Affine):
            return _Partial(dict(meaning.terms), meaning.constant, 0.0, {meaning.dimension})
        return _Partial({name: 1.0}, dims={str(meaning)})


def parse_affine(text: object, symbols: SymbolTable, where: str, *, length_scale: float,
                 expect: str | None = None) -> Affine:
    """The expression ``text`` (a string, or a plain number) over ``symbols`` as an
    :class:`Affine` in SI. ``length_scale`` converts a bare number to metres (1e-3 for a file
    in mm); ``expect`` the dimension required (None: whatever the terms say, a bare number
    alone being a length). ConfigError names ``where``, the text and the problem."""
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ConfigError(f'{where} = {text!r}: expected an expression or a number')
    if isinstance(text, (int, float)):
        if not math.isfinite(text):
            raise ConfigError(f'{where} = {text!r}: not a finite number')
        partial = _Partial(bare=float(text), has_bare=True)
    else:
        partial = _Parser(text, symbols, where).parse()
    if len(partial.dims) > 1:
        raise ConfigError(f'{where} = {text!r}: mixes lengths and angles')
    dim = next(iter(partial.dims)) if partial.dims else (expect or LENGTH)
    if expect is not None and dim != expect:
        raise ConfigError(f'{where} = {text!r}: is {"an" if dim == ANGLE else "a"} {dim}, '
                          f'expected {"an" if expect == ANGLE else "a"} {expect}')
    constant = partial.si
    if partial.has_bare and partial.bare != 0.0:
        if dim == ANGLE:
            raise ConfigError(f'{where} = {text!r}: an angle constant needs a unit (deg or '
                              'rad)')
        constant += partial.bare * length_scale
    if not math.isfinite(constant) or not all(math.isfinite(v) for v in partial.coefs.values()):
        raise ConfigError(f'{where} = {text!r}: not finite')
    terms = tuple((k, v) for k, v in partial.coefs.items() if v != 0.0)
    return Affine(terms, constant, dim)


def parse_quantity(value: object, where: str, *, length_scale: float,
                   expect: str | None = None) -> Affine:
    """A constant (no symbols): a number (a length in the file's unit) or a string with a
    unit (``84 deg``, ``0.25 mm``); see :func:`parse_affine`."""
    return parse_affine(value, {}, where, length_scale=length_scale, expect=expect)
