"""A mechanism for tolerance analysis, as data (seed 004 §2-3): closed vector loops h = 0 that
fix the unknowns (joint variables, assembly dimensions), open loops that give the assembly
dimensions the requirements are on, every length and angle an affine expression of named
symbols, and gap connectors for the clearance of the joints.

Symbols (all SI inside: m, rad):

- **sources**: toleranced dimensions x_i (nominal, ± tolerance, law: ``normal`` with
  tolerance = ``sigmas``·σ (3 by default), truncated there; or ``uniform`` on ± tolerance);
- **unknowns**: what the closed loops solve for, with a starting value (the nominal);
- **inputs**: fixed values, e.g. the drive angle θ (not toleranced);
- derived: a gap connector's length and orientation angle.

Gap connectors (seed 004 §2): joint i–j with clearance r_ij (eq. 1: r_i − r_j, from two radius
sources, or a clearance source of its own) whose direction α follows the motion: the driving
member rotates (``follows: rotation``, α = θ ± 90°, eq. 2) or translates (``follows:
translation``, α = θ ± 45°, eq. 3), + for a counter-clockwise sense; or the load
(``load: <angle>``) or a fixed ``angle``. α is a symbol (``alpha_<gap>`` or the ``alpha`` key)
usable in any angle; a vector ``{gap: r12}`` is the connector itself (length r12, angle α).

The file (YAML; :func:`load_mechanism`; the same mapping for :func:`parse_mechanism`; the
shipped ``examples/four_bar.yaml`` is a whole one)::

    name: a slider-crank with a clearance
    units: {length: mm}              # bare numbers are mm (or m); angles need deg or rad
    space: planar                    # planar: loops close in x, y; spatial: x, y, z
    inputs: {theta: 30 deg}          # the crank angle
    sources:
      r: {nominal: 40, tolerance: 0.02}              # normal, 3σ = 0.02 mm, truncated there
      l: {nominal: 120, tolerance: 0.05, distribution: uniform}
      e: {nominal: 0, tolerance: 0.05}               # the slide's offset
    unknowns: {phi: -10 deg, s: 150}                 # starting values of the nominal solve
    gaps:
      c: {clearance: {nominal: 0.1, tolerance: 0.01}, follows: rotation, input: theta,
          sense: ccw}                # α = θ + 90° (seed 004 eq. 2)
    closed_loops:
      loop:
        vectors:                     # Σ L·(cos φ, sin φ) = 0
          - {length: r, angle: theta}
          - {gap: c}                 # length c, angle alpha_c
          - {length: l, angle: phi}
          - {length: -s, angle: 0 deg}
          - {length: -e, angle: 90 deg}
        components: [x, y]           # default: all of the space's
        equations: {}                # scalar equations = 0 (seed 004's h_θ), if any
    open_loops:
      stroke:
        expression: s                # or vectors + component (x|y|z) + offset
        requirement: {tolerance: 0.1}           # or nominal, lower/upper (deviations)

Spatial vectors: ``{length, azimuth, elevation}`` (direction (cos e cos a, cos e sin a,
sin e)) or ``{length, direction: [ux, uy, uz]}``. Every refusal is a ConfigError naming the
file, the key and the value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from scipy.stats import truncnorm

from positioning_cell import files
from positioning_cell.config import load_yaml_mapping
from positioning_cell.errors import ConfigError
from positioning_cell.tolerance.expressions import (
    ANGLE,
    LENGTH,
    LENGTH_UNITS,
    UNITS,
    Affine,
    SymbolTable,
    parse_affine,
    parse_quantity,
)

SPACES = ('planar', 'spatial')
COMPONENTS = {'planar': ('x', 'y'), 'spatial': ('x', 'y', 'z')}
DISTRIBUTIONS = ('normal', 'uniform')
#: Default truncation of the normal law, in σ: tolerance = 3σ.
DEFAULT_SIGMAS = 3.0
_TOP_KEYS = ('name', 'description', 'units', 'space', 'inputs', 'sources', 'unknowns', 'gaps',
             'closed_loops', 'open_loops')
_SOURCE_KEYS = ('nominal', 'tolerance', 'distribution', 'sigmas', 'note')
_GAP_KEYS = ('clearance', 'radii', 'follows', 'input', 'sense', 'load', 'angle', 'alpha',
             'note')
_CLOSED_KEYS = ('vectors', 'components', 'equations', 'note')
_OPEN_KEYS = ('vectors', 'component', 'offset', 'expression', 'requirement', 'note')
_VECTOR_KEYS = ('length', 'angle', 'azimuth', 'elevation', 'direction', 'gap', 'label')
_REQUIREMENT_KEYS = ('nominal', 'tolerance', 'lower', 'upper')
#: α − θ of the gap rules (seed 004 eqs. 2-3), counter-clockwise; clockwise negates it.
_RULE_OFFSET = {'rotation': 90.0, 'translation': 45.0}
_SENSES = {'ccw': 1.0, 'cw': -1.0}


@dataclass(frozen=True)
class Source:
    """A toleranced dimension: ``nominal`` ± ``tolerance`` (SI: m or rad; tolerance ≥ 0),
    drawn from ``distribution``: ``normal`` with tolerance = ``sigmas``·σ, truncated at the
    tolerance, or ``uniform`` on ± tolerance. ``origin`` says where it comes from when a gap
    connector made it (``gap r12``)."""

    name: str
    dimension: str
    nominal: float
    tolerance: float
    distribution: str = 'normal'
    sigmas: float = DEFAULT_SIGMAS
    origin: str = ''

    @property
    def std(self) -> float:
        """The standard deviation of the law (SI)."""
        if self.distribution == 'uniform':
            return self.tolerance / math.sqrt(3.0)
        k = self.sigmas
        return self.tolerance / k * float(truncnorm.std(-k, k))


@dataclass(frozen=True)
class Input:
    """A fixed value (SI), e.g. the drive angle θ; not toleranced."""

    name: str
    dimension: str
    value: float


@dataclass(frozen=True)
class Unknown:
    """A variable the closed loops solve for, and its starting value ``guess`` (SI): the
    nominal solution is the one Newton reaches from it."""

    name: str
    dimension: str
    guess: float


@dataclass(frozen=True)
class GapConnector:
    """A clearance joint as a massless link (seed 004 §2): ``length`` (the clearance r_ij,
    eq. 1) and orientation ``alpha`` (named ``alpha_name``), ``rule`` in words."""

    name: str
    length: Affine
    alpha: Affine
    alpha_name: str
    rule: str


@dataclass(frozen=True)
class Vector:
    """L·(cos e·cos a, cos e·sin a, sin e): ``length`` L, ``azimuth`` a (the planar angle φ)
    and ``elevation`` e (0 in a planar mechanism), each affine; ``label`` for reports."""

    length: Affine
    azimuth: Affine
    elevation: Affine
    label: str


@dataclass(frozen=True)
class Equation:
    """A scalar equation ``expression`` = 0 of a closed loop (e.g. seed 004's h_θ)."""

    name: str
    expression: Affine


@dataclass(frozen=True)
class ClosedLoop:
    """A closed loop: Σ vectors = 0 in each of ``components`` and every scalar equation."""

    name: str
    vectors: tuple[Vector, ...]
    components: tuple[str, ...]
    equations: tuple[Equation, ...]

    @property
    def equation_names(self) -> tuple[str, ...]:
        """``<loop>: x``, ``<loop>: y``, ..., ``<loop>: <equation>``: rows of U and A."""
        return (*(f'{self.name}: {c}' for c in self.components),
                *(f'{self.name}: {e.name}' for e in self.equations))


@dataclass(frozen=True)
class Requirement:
    """Limits of an assembly dimension: deviations ``lower`` ≤ value − reference ≤ ``upper``
    (SI), reference = ``nominal`` (the design value) or, when None, the computed nominal."""

    lower: float
    upper: float
    nominal: float | None = None


@dataclass(frozen=True)
class OpenLoop:
    """An assembly dimension (seed 004 eq. 6, Gap): the ``component`` of the sum of
    ``vectors`` plus ``linear`` (an affine expression: the offset, or the whole dimension when
    there are no vectors), of ``dimension``; with its ``requirement`` if any."""

    name: str
    dimension: str
    vectors: tuple[Vector, ...]
    component: str | None
    linear: Affine
    requirement: Requirement | None


@dataclass(frozen=True)
class Mechanism:
    """The whole mechanism (module docstring); ``origin`` the file it came from."""

    name: str
    description: str
    length_unit: str
    space: str
    inputs: tuple[Input, ...]
    sources: tuple[Source, ...]
    unknowns: tuple[Unknown, ...]
    gaps: tuple[GapConnector, ...]
    closed_loops: tuple[ClosedLoop, ...]
    open_loops: tuple[OpenLoop, ...]
    origin: str = '<dict>'

    @property
    def length_scale(self) -> float:
        """Metres per file length unit."""
        return UNITS[self.length_unit][1]

    @cached_property
    def source_names(self) -> tuple[str, ...]:
        """Names of the sources, in order (columns of A and C)."""
        return tuple(s.name for s in self.sources)

    @cached_property
    def unknown_names(self) -> tuple[str, ...]:
        """Names of the unknowns, in order (columns of U and D)."""
        return tuple(u.name for u in self.unknowns)

    @cached_property
    def equation_names(self) -> tuple[str, ...]:
        """Names of the closure equations (rows of A and U)."""
        return tuple(n for loop in self.closed_loops for n in loop.equation_names)

    @cached_property
    def open_loop_names(self) -> tuple[str, ...]:
        """Names of the assembly dimensions (rows of C and D)."""
        return tuple(o.name for o in self.open_loops)

    def with_inputs(self, **values: float) -> Mechanism:
        """The same mechanism with some inputs set to other values (SI)."""
        names = {i.name for i in self.inputs}
        for key, value in values.items():
            if key not in names:
                raise ConfigError(f'{self.origin}: no input {key!r} (inputs: '
                                  f'{", ".join(sorted(names)) or "none"})')
            if not math.isfinite(value):
                raise ConfigError(f'{self.origin}: input {key} = {value!r}: not finite')
        return replace(self, inputs=tuple(replace(i, value=float(values.get(i.name, i.value)))
                                          for i in self.inputs))

    def display(self, value: float, dimension: str) -> float:
        """A SI value in the report's unit: the file's length unit, or degrees."""
        return value / self.length_scale if dimension == LENGTH else math.degrees(value)

    def unit(self, dimension: str) -> str:
        """The report's unit of ``dimension``: the file's length unit or ``deg``."""
        return self.length_unit if dimension == LENGTH else 'deg'


# -- the loader ---------------------------------------------------------------------------
class _Reader:
    """Parses one file's mapping; every error names ``origin`` and the key path."""

    def __init__(self, data: Mapping[str, Any], origin: str) -> None:
        self.data, self.origin = data, origin
        self.scale = 1.0
        self.space = 'planar'
        self.symbols: dict[str, str | Affine] = {}
        self.kinds: dict[str, str] = {}
        #: Gap name → the symbol of its orientation angle (a vector ``{gap: name}``).
        self.alpha_of: dict[str, str] = {}

    def fail(self, key: str, value: Any, why: str) -> ConfigError:
        return ConfigError(f'{self.origin}: {key} = {files.excerpt(value)}: {why}')

    def where(self, key: str) -> str:
        return f'{self.origin}: {key}'

    def mapping(self, key: str, value: Any, keys: Sequence[str] | None = None,
                required: Sequence[str] = ()) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(key, value, 'expected a mapping')
        if keys is not None:
            for k in value:
                if k not in keys:
                    raise ConfigError(f'{self.origin}: {key}: unknown key {files.excerpt(k)} '
                                      f'(known: {", ".join(keys)})')
        for k in required:
            if k not in value:
                raise ConfigError(f'{self.origin}: {key}: missing key {k!r}')
        return value

    def declare(self, key: str, name: Any, kind: str, meaning: str | Affine) -> str:
        if not isinstance(name, str) or not name.isidentifier():
            raise self.fail(key, name, 'a name must be an identifier (letters, digits, _)')
        if name in UNITS or name.lower() in ('nan', 'inf', 'infinity'):
            raise self.fail(key, name, 'reserved word (a unit or a number)')
        if name in self.symbols:
            raise self.fail(key, name, f'already declared as {self.kinds[name]}')
        self.symbols[name] = meaning
        self.kinds[name] = kind
        return name

    def affine(self, key: str, value: Any, expect: str | None = None,
               symbols: SymbolTable | None = None) -> Affine:
        return parse_affine(value, self.symbols if symbols is None else symbols,
                            self.where(key), length_scale=self.scale, expect=expect)

    def quantity(self, key: str, value: Any, expect: str | None = None) -> Affine:
        return parse_quantity(value, self.where(key), length_scale=self.scale, expect=expect)

    def read(self) -> Mechanism:
        data = self.mapping('file', self.data, _TOP_KEYS,
                            ('units', 'sources', 'unknowns', 'closed_loops'))
        units = self.mapping('units', data['units'], ('length',), ('length',))
        if units['length'] not in LENGTH_UNITS:
            raise self.fail('units.length', units['length'],
                            f'expected one of {", ".join(LENGTH_UNITS)}')
        self.scale = UNITS[units['length']][1]
        self.space = data.get('space', 'planar')
        if self.space not in SPACES:
            raise self.fail('space', self.space, f'expected one of {", ".join(SPACES)}')
        inputs = self.inputs(data.get('inputs') or {})
        sources = self.sources(data['sources'])
        unknowns = self.unknowns(data['unknowns'])
        gaps, gap_sources = self.gaps(data.get('gaps') or {})
        closed = self.closed_loops(data['closed_loops'])
        opened = self.open_loops(data.get('open_loops') or {})
        mech = Mechanism(str(data.get('name', Path(self.origin).stem)),
                         str(data.get('description', '')), str(units['length']), self.space,
                         inputs, (*sources, *gap_sources), unknowns, gaps, closed, opened,
                         self.origin)
        self.check_counts(mech)
        return mech

    def inputs(self, block: Any) -> tuple[Input, ...]:
        out = []
        for name, value in self.mapping('inputs', block).items():
            q = self.quantity(f'inputs.{name}', value)
            dim = q.dimension
            out.append(Input(self.declare(f'inputs.{name}', name, 'an input', dim), dim,
                             q.constant))
        return tuple(out)

    def source(self, key: str, name: str, spec: Any, origin: str = '') -> Source:
        spec = self.mapping(key, spec, _SOURCE_KEYS, ('nominal', 'tolerance'))
        nominal = self.quantity(f'{key}.nominal', spec['nominal'])
        dim = nominal.dimension
        tol_value = spec['tolerance']
        if dim == ANGLE and isinstance(tol_value, (int, float)) and tol_value != 0:
            raise self.fail(f'{key}.tolerance', tol_value, 'bad unit: the tolerance of an '
                            'angle needs deg or rad')
        tolerance = self.quantity(f'{key}.tolerance', tol_value, dim).constant
        if tolerance < 0.0:
            raise self.fail(f'{key}.tolerance', tol_value, 'a tolerance must be >= 0')
        law = spec.get('distribution', 'normal')
        if law not in DISTRIBUTIONS:
            raise self.fail(f'{key}.distribution', law,
                            f'expected one of {", ".join(DISTRIBUTIONS)}')
        sigmas = spec.get('sigmas', DEFAULT_SIGMAS)
        if isinstance(sigmas, bool) or not isinstance(sigmas, (int, float)) or not (
                math.isfinite(sigmas) and sigmas > 0.0):
            raise self.fail(f'{key}.sigmas', sigmas, 'expected a finite number > 0')
        if 'sigmas' in spec and law != 'normal':
            raise self.fail(f'{key}.sigmas', sigmas, 'only a normal law has sigmas')
        self.declare(key, name, 'a source', dim)
        return Source(name, dim, nominal.constant, tolerance, law, float(sigmas), origin)

    def sources(self, block: Any) -> tuple[Source, ...]:
        return tuple(self.source(f'sources.{name}', name, spec)
                     for name, spec in self.mapping('sources', block).items())

    def unknowns(self, block: Any) -> tuple[Unknown, ...]:
        block = self.mapping('unknowns', block)
        if not block:
            raise self.fail('unknowns', dict(block), 'at least one unknown is needed')
        out = []
        for name, value in block.items():
            q = self.quantity(f'unknowns.{name}', value)
            out.append(Unknown(self.declare(f'unknowns.{name}', name, 'an unknown',
                                            q.dimension), q.dimension, q.constant))
        return tuple(out)

    def gaps(self, block: Any) -> tuple[tuple[GapConnector, ...], tuple[Source, ...]]:
        gaps, made = [], []
        for name, given in self.mapping('gaps', block).items():
            key = f'gaps.{name}'
            spec = self.mapping(key, given, _GAP_KEYS)
            if ('clearance' in spec) == ('radii' in spec):
                raise ConfigError(f'{self.origin}: {key}: give either clearance (nominal, '
                                  'tolerance) or radii [hole, pin]')
            if 'clearance' in spec:
                src = self.source(f'{key}.clearance', name, spec['clearance'], f'gap {name}')
                if src.dimension != LENGTH:
                    raise self.fail(f'{key}.clearance.nominal', spec['clearance']['nominal'],
                                    'a clearance is a length')
                made.append(src)
                length = Affine.of(name, LENGTH)
            else:
                radii = spec['radii']
                if not (isinstance(radii, Sequence) and not isinstance(radii, str)
                        and len(radii) == 2):
                    raise self.fail(f'{key}.radii', radii, 'expected [hole radius, pin '
                                    'radius] (two source names)')
                length = self.affine(f'{key}.radii', f'({radii[0]}) - ({radii[1]})', LENGTH)
                self.declare(key, name, 'a gap connector', length)
            alpha, rule = self.gap_direction(key, spec)
            alpha_name = spec.get('alpha', f'alpha_{name}')
            self.declare(f'{key}.alpha', alpha_name, 'a gap orientation angle', alpha)
            self.alpha_of[name] = alpha_name
            gaps.append(GapConnector(name, length, alpha, alpha_name, rule))
        return tuple(gaps), tuple(made)

    def gap_direction(self, key: str, spec: Mapping[str, Any]) -> tuple[Affine, str]:
        given = [k for k in ('follows', 'load', 'angle') if k in spec]
        if len(given) != 1:
            raise ConfigError(f'{self.origin}: {key}: give one of follows (rotation | '
                              'translation, with input and sense), load or angle')
        kind = given[0]
        if kind != 'follows':
            for k in ('input', 'sense'):
                if k in spec:
                    raise ConfigError(f'{self.origin}: {key}: {k} only with follows')
            alpha = self.affine(f'{key}.{kind}', spec[kind], ANGLE)
            return alpha, f'{kind}: α = {spec[kind]}'
        follows = spec['follows']
        if follows not in _RULE_OFFSET:
            raise self.fail(f'{key}.follows', follows, 'expected rotation or translation')
        for k in ('input', 'sense'):
            if k not in spec:
                raise ConfigError(f'{self.origin}: {key}: missing key {k!r} (follows needs '
                                  'the input angle and the sense of motion)')
        sense = spec['sense']
        if sense not in _SENSES:
            raise self.fail(f'{key}.sense', sense, 'expected ccw or cw')
        theta = self.affine(f'{key}.input', spec['input'], ANGLE)
        offset = math.radians(_RULE_OFFSET[follows]) * _SENSES[sense]
        eq = 'eq. 2' if follows == 'rotation' else 'eq. 3'
        sign = '+' if sense == 'ccw' else '−'
        rule = (f'follows {follows} ({sense}): α = {spec["input"]} {sign} '
                f'{_RULE_OFFSET[follows]:g}° (seed 004 {eq})')
        return Affine(theta.terms, theta.constant + offset, ANGLE), rule

    def vectors(self, key: str, block: Any) -> tuple[Vector, ...]:
        if not isinstance(block, Sequence) or isinstance(block, str) or not block:
            raise self.fail(key, block, 'expected a list of vectors')
        return tuple(self.vector(f'{key}[{i}]', v) for i, v in enumerate(block))

    def vector(self, key: str, spec: Any) -> Vector:
        spec = self.mapping(key, spec, _VECTOR_KEYS)
        zero = Affine.zero(ANGLE)
        if 'gap' in spec:
            gap = spec['gap']
            alpha_name = self.alpha_of.get(str(gap))
            gap_alpha = self.symbols.get(alpha_name) if alpha_name else None
            if not isinstance(gap_alpha, Affine):
                raise self.fail(f'{key}.gap', gap, 'not a gap connector (gaps: '
                                f'{", ".join(self.alpha_of) or "none"})')
            if 'length' in spec:
                raise ConfigError(f'{self.origin}: {key}: a gap vector takes its length from '
                                  'the gap connector')
            length = self.affine(f'{key}.gap', str(gap), LENGTH)
            default_angle: Affine | None = gap_alpha
        else:
            if 'length' not in spec:
                raise ConfigError(f'{self.origin}: {key}: missing key \'length\'')
            length = self.affine(f'{key}.length', spec['length'], LENGTH)
            default_angle = None
        label = str(spec.get('label', spec.get('gap', spec.get('length'))))
        if self.space == 'planar':
            for k in ('azimuth', 'elevation', 'direction'):
                if k in spec:
                    raise ConfigError(f'{self.origin}: {key}: {k} is for a spatial '
                                      'mechanism (space: spatial); a planar vector has angle')
            if 'angle' in spec:
                angle = self.affine(f'{key}.angle', spec['angle'], ANGLE)
            elif default_angle is not None:
                angle = default_angle
            else:
                raise ConfigError(f'{self.origin}: {key}: missing key \'angle\'')
            return Vector(length, angle, zero, label)
        if 'angle' in spec and 'gap' not in spec:
            raise ConfigError(f'{self.origin}: {key}: a spatial vector has azimuth and '
                              'elevation, or direction')
        if 'direction' in spec:
            if any(k in spec for k in ('azimuth', 'elevation', 'angle')):
                raise ConfigError(f'{self.origin}: {key}: direction excludes azimuth and '
                                  'elevation')
            return Vector(length, *self.direction(f'{key}.direction', spec['direction']),
                          label)
        azimuth = (self.affine(f'{key}.azimuth', spec['azimuth'], ANGLE) if 'azimuth' in spec
                   else self.affine(f'{key}.angle', spec['angle'], ANGLE) if 'angle' in spec
                   else default_angle)
        if azimuth is None:
            raise ConfigError(f'{self.origin}: {key}: missing key \'azimuth\' (or direction)')
        elevation = (self.affine(f'{key}.elevation', spec['elevation'], ANGLE)
                     if 'elevation' in spec else zero)
        return Vector(length, azimuth, elevation, label)

    def direction(self, key: str, value: Any) -> tuple[Affine, Affine]:
        ok = (isinstance(value, Sequence) and not isinstance(value, str) and len(value) == 3
              and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      and math.isfinite(v) for v in value))
        norm = math.sqrt(sum(float(v) ** 2 for v in value)) if ok else 0.0
        if not ok or norm == 0.0:
            raise self.fail(key, value, 'expected three finite numbers, not all 0')
        x, y, z = (float(v) / norm for v in value)
        return (Affine((), math.atan2(y, x), ANGLE),
                Affine((), math.asin(max(-1.0, min(1.0, z))), ANGLE))

    def closed_loops(self, block: Any) -> tuple[ClosedLoop, ...]:
        block = self.mapping('closed_loops', block)
        if not block:
            raise self.fail('closed_loops', dict(block), 'at least one closed loop is needed')
        out = []
        for name, given in block.items():
            key = f'closed_loops.{name}'
            if not isinstance(name, str) or not name:
                raise self.fail(key, name, 'a loop needs a name')
            spec = self.mapping(key, given, _CLOSED_KEYS)
            vectors = self.vectors(f'{key}.vectors', spec['vectors']) if 'vectors' in spec \
                else ()
            all_components = COMPONENTS[self.space]
            components = tuple(spec.get('components', all_components if vectors else ()))
            for c in components:
                if c not in all_components:
                    raise self.fail(f'{key}.components', list(components),
                                    f'expected a list of {", ".join(all_components)}')
            if len(set(components)) != len(components):
                raise self.fail(f'{key}.components', list(components), 'repeated component')
            if components and not vectors:
                raise ConfigError(f'{self.origin}: {key}: components without vectors')
            equations = self.equations(f'{key}.equations', spec.get('equations') or {})
            if not components and not equations:
                raise ConfigError(f'{self.origin}: {key}: a closed loop needs vectors or '
                                  'equations')
            out.append(ClosedLoop(name, vectors, components, equations))
        return tuple(out)

    def equations(self, key: str, block: Any) -> tuple[Equation, ...]:
        if isinstance(block, Mapping):
            items = [(str(k), v) for k, v in block.items()]
        elif isinstance(block, Sequence) and not isinstance(block, str):
            items = [(f'e{i + 1}', v) for i, v in enumerate(block)]
        else:
            raise self.fail(key, block, 'expected a mapping name -> expression (= 0) or a '
                            'list of expressions')
        return tuple(Equation(n, self.affine(f'{key}.{n}', v)) for n, v in items)

    def open_loops(self, block: Any) -> tuple[OpenLoop, ...]:
        out = []
        for name, given in self.mapping('open_loops', block).items():
            key = f'open_loops.{name}'
            spec = self.mapping(key, given, _OPEN_KEYS)
            if ('expression' in spec) == ('vectors' in spec):
                raise ConfigError(f'{self.origin}: {key}: give either vectors (with '
                                  'component) or expression')
            if 'expression' in spec:
                for k in ('component', 'offset'):
                    if k in spec:
                        raise ConfigError(f'{self.origin}: {key}: {k} only with vectors')
                linear = self.affine(f'{key}.expression', spec['expression'])
                vectors: tuple[Vector, ...] = ()
                component = None
            else:
                vectors = self.vectors(f'{key}.vectors', spec['vectors'])
                component = spec.get('component')
                if component not in COMPONENTS[self.space]:
                    raise self.fail(f'{key}.component', component,
                                    f'expected one of {", ".join(COMPONENTS[self.space])}')
                linear = (self.affine(f'{key}.offset', spec['offset'], LENGTH)
                          if 'offset' in spec else Affine.zero(LENGTH))
            req = (self.requirement(f'{key}.requirement', spec['requirement'],
                                    linear.dimension) if 'requirement' in spec else None)
            out.append(OpenLoop(str(name), linear.dimension, vectors, component, linear, req))
        return tuple(out)

    def requirement(self, key: str, spec: Any, dim: str) -> Requirement:
        spec = self.mapping(key, spec, _REQUIREMENT_KEYS)
        nominal = (self.quantity(f'{key}.nominal', spec['nominal'], dim).constant
                   if 'nominal' in spec else None)
        if 'tolerance' in spec:
            if 'lower' in spec or 'upper' in spec:
                raise ConfigError(f'{self.origin}: {key}: tolerance excludes lower/upper')
            t = self.quantity(f'{key}.tolerance', spec['tolerance'], dim).constant
            if t <= 0.0:
                raise self.fail(f'{key}.tolerance', spec['tolerance'], 'must be > 0')
            return Requirement(-t, t, nominal)
        if 'lower' not in spec or 'upper' not in spec:
            raise ConfigError(f'{self.origin}: {key}: give tolerance, or lower and upper '
                              '(deviations from the nominal)')
        lower = self.quantity(f'{key}.lower', spec['lower'], dim).constant
        upper = self.quantity(f'{key}.upper', spec['upper'], dim).constant
        if not lower < upper:
            raise self.fail(key, dict(spec), 'lower must be below upper')
        return Requirement(lower, upper, nominal)

    def check_counts(self, mech: Mechanism) -> None:
        equations, unknowns = mech.equation_names, mech.unknown_names
        if len(equations) != len(unknowns):
            raise ConfigError(
                f'{self.origin}: closed_loops: {len(equations)} closure equations '
                f'({", ".join(equations)}) for {len(unknowns)} unknowns ({", ".join(unknowns)})'
                ': the closed loops must give one scalar equation per unknown')
        used: set[str] = set()
        for loop in mech.closed_loops:
            for v in loop.vectors:
                used.update(v.length.symbols + v.azimuth.symbols + v.elevation.symbols)
            for e in loop.equations:
                used.update(e.expression.symbols)
        for u in unknowns:
            if u not in used:
                raise ConfigError(f'{self.origin}: unknowns.{u}: appears in no closed loop')


def parse_mechanism(data: Mapping[str, Any], origin: str = '<dict>') -> Mechanism:
    """A :class:`Mechanism` from the parsed mapping of a mechanism file (module docstring);
    ConfigError names ``origin``, the key and the value of the first problem."""
    return _Reader(data, origin).read()


def load_mechanism(path: str | Path) -> Mechanism:
    """Read and parse a mechanism file (YAML, read by :func:`positioning_cell.files.load_yaml`:
    a regular file of at most :data:`~positioning_cell.files.MECHANISM_FILE`'s size); a short
    ConfigError names the file, the key and the value (a missing file, one that is not a
    regular file or too large, invalid or refused YAML, any refusal of
    :func:`parse_mechanism`)."""
    data = load_yaml_mapping(path, files.MECHANISM_FILE,
                             'name, units, sources, unknowns, closed_loops, ...')
    with files.brief_errors():
        return parse_mechanism(data, str(path))
