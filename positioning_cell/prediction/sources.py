"""Error sources of the 3-UPS positioner and the tolerance spec that bounds them (seed 004 §1-2).

Every source is one scalar x_i with a symmetric bound |x_i| ≤ bound_i, SI units:

====================  ====  ========================================================  =========
kind                  unit  what                                                      per leg
====================  ====  ========================================================  =========
``leg_length``        m     zero offset of the leg length: l_true = l_cmd + x         1
``u_centre``          m     U-joint centre A_i error, base frame (_x, _y, _z)         3
``s_centre``          m     S-joint centre b_i error, platform frame                  3
``u_clearance``       m     U-joint clearance r_a: A_i moves by e_a, |e_a| ≤ r_a      1 or 3
``s_clearance``       m     S-joint clearance r_b: B_i moves by e_b, |e_b| ≤ r_b      1 or 3
``encoder_length``    m     linear encoder quantisation; spec value = resolution q    1
``encoder_theta``     rad   rotary (θ) encoder quantisation; spec value = resolution  1
====================  ====  ========================================================  =========

Names are ``<kind>_<leg>`` or ``<kind>_<leg>_<axis>`` (``u_centre_2_x``); a spec key may also
name a whole kind (``u_centre``) or one leg of it (``u_centre_2``). Gap connectors (seed 004 §2)
have a length bounded by the joint clearance r; their direction is set by :class:`GapModel`:

- ``any`` (the default): the joint's offset e may point anywhere, |e| ≤ r (the exact vector
  model, :class:`positioning_cell.clearance.VectorClearance`). Each clearance is then three
  sources ``<kind>_<leg>_x/_y/_z``, the components of e (U joint: base frame; S joint: platform
  frame, as the vector model's ``u_offsets`` / ``s_offsets``), bounded *jointly* by the ball
  |e| ≤ r (:attr:`ToleranceSpec.balls`); the spec names the joint (``u_clearance_2``), never
  one component. Sampled, e = x·d with x from the source's law and d uniform on the sphere.
- ``leg`` / ``motion``: one scalar x ∈ [−r, r] along a fixed unit direction d (the leg axis, or
  the joint's velocity); the sign is unknown to a prediction. Exact for seed 000 eq. 9, which
  sees a gap only through its projection on the leg, but not a bound of all gap directions.

Encoder errors are uniform on ±q/2; the other kinds default to a normal law with
bound = 3σ, truncated at the bound (parts inspected to their tolerance).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import truncnorm

from positioning_cell.config import load_parameter_file
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError
from positioning_cell.files import excerpt, shorten
from positioning_cell.tolerance.sampling import draw_laws

FloatArray = NDArray[np.float64]

#: The kinds of source, in the order sources are listed.
KINDS = ('leg_length', 'u_centre', 's_centre', 'u_clearance', 's_clearance',
         'encoder_length', 'encoder_theta')
_AXES = ('x', 'y', 'z')
_VECTOR_KINDS = ('u_centre', 's_centre')
_ANGLE_KINDS = ('encoder_theta',)
#: bound = factor · spec value (an encoder of resolution q errs by at most q/2).
_BOUND_FACTOR = {'encoder_length': 0.5, 'encoder_theta': 0.5}
_DEFAULT_DISTRIBUTION = {'leg_length': 'normal', 'u_centre': 'normal', 's_centre': 'normal',
                         'u_clearance': 'uniform', 's_clearance': 'uniform',
                         'encoder_length': 'uniform', 'encoder_theta': 'uniform'}
DISTRIBUTIONS = ('normal', 'uniform')
#: Largest spec value accepted, SI: beyond it the spec is almost surely in mm or degrees, and
#: a first-order expansion would mean little anyway.
_MAX_LENGTH = 5e-3
_MAX_ANGLE = 0.05
#: Truncation of the normal law, in σ (bound = 3σ).
_SIGMAS = 3.0
_GAP_MODES = ('any', 'leg', 'motion')
#: Kinds that are one joint's offset vector in the ``any`` gap model (a ball of radius r).
BALL_KINDS = ('u_clearance', 's_clearance')
_SPEC_KEYS = ('tolerances', 'distributions', 'requirement', 'clearance_direction', 'motion')


@dataclass(frozen=True)
class ErrorSource:
    """One scalar error source: |x| ≤ ``bound`` (m or rad, see ``unit``), drawn from
    ``distribution``. ``tolerance`` is the spec value (for encoders the resolution, bound = q/2).
    ``leg`` is 1-based; ``axis`` is 'x', 'y', 'z' for joint-centre errors and for the offset
    components of a clearance in the ``any`` gap model, else None."""

    name: str
    kind: str
    leg: int
    axis: str | None
    tolerance: float
    distribution: str

    @property
    def unit(self) -> str:
        """'rad' for the rotary encoder, 'm' otherwise."""
        return 'rad' if self.kind in _ANGLE_KINDS else 'm'

    @property
    def in_ball(self) -> bool:
        """True for one component of a clearance offset vector (``any`` gap model): bounded with
        its two siblings by |e| ≤ ``bound``, not on its own."""
        return self.kind in BALL_KINDS and self.axis is not None

    @property
    def bound(self) -> float:
        """Half-width of the source's range (m or rad); of a ball component, the ball radius."""
        return self.tolerance * _BOUND_FACTOR.get(self.kind, 1.0)

    @property
    def std(self) -> float:
        """Standard deviation of the source's law (m or rad). A ball component is one
        coordinate of x·d, d uniform on the sphere: E[d_k²] = 1/3, so σ_x/√3 (and the three
        are uncorrelated)."""
        if self.distribution == 'uniform':
            std = self.bound / math.sqrt(3.0)
        else:
            std = self.bound / _SIGMAS * float(truncnorm.std(-_SIGMAS, _SIGMAS))
        return std / math.sqrt(3.0) if self.in_ball else std


@dataclass(frozen=True)
class Requirement:
    """What the pose must meet: |Δp| ≤ ``position`` (m) and the angle of R_nomᵀ·R ≤
    ``orientation`` (rad)."""

    position: float
    orientation: float


@dataclass(frozen=True)
class GapModel:
    """Direction of the gap connectors (seed 004 §2).

    ``'any'`` (default): every direction; each joint's offset is a vector in the ball of radius
    r (exact vector model, docs/conventions/kinematics.md), so the worst case bounds all gap
    directions
    (:func:`.sensitivity.worst_case`, :func:`.extremes.worst_norm`).
    ``'leg'``: the joint is loaded along the leg (a UPS leg carries mainly axial force), so the
    clearance is taken up along the leg axis u_i. The worst direction only under seed 000
    eq. 9; under the vector model a gap tangential to the leg moves the platform further.
    ``'motion'``: the direction follows the motion (seed 004 eq. 2: the gap vector lies along the
    velocity of the moving member): for a platform twist ``twist`` = (v m/s, ω rad/s) in the
    base frame, the S joint's gap points along the ball's velocity v + ω × R·b_i and the U joint's
    along that velocity's component normal to the leg (the leg swings about the U). Where a
    velocity vanishes, the leg axis is used.
    """

    mode: str = 'any'
    twist: tuple[float, float, float, float, float, float] = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.mode not in _GAP_MODES:
            raise ConfigError(
                f'clearance_direction = {excerpt(self.mode)}: expected one of '
                f'{", ".join(_GAP_MODES)}')
        if len(self.twist) != 6 or not all(math.isfinite(v) for v in self.twist):
            raise ConfigError(f'motion = {excerpt(self.twist)}: expected 6 finite numbers (v, ω)')


@dataclass(frozen=True)
class ToleranceSpec:
    """The sources (all of them, in catalogue order; tolerance 0 where the spec is silent),
    the requirement the pose must meet and the gap-connector model."""

    sources: tuple[ErrorSource, ...]
    requirement: Requirement
    gap: GapModel

    @cached_property
    def names(self) -> tuple[str, ...]:
        """Source names, in order."""
        return tuple(s.name for s in self.sources)

    @cached_property
    def bounds(self) -> FloatArray:
        """Half-widths (S,), m or rad."""
        return np.array([s.bound for s in self.sources])

    @cached_property
    def stds(self) -> FloatArray:
        """Standard deviations (S,), m or rad."""
        return np.array([s.std for s in self.sources])

    @cached_property
    def law_runs(self) -> tuple[tuple[int, int, str], ...]:
        """Runs of consecutive sources with the same law: (first, stop, law), stop exclusive."""
        runs: list[tuple[int, int, str]] = []
        for i, src in enumerate(self.sources):
            if runs and runs[-1][2] == src.distribution:
                runs[-1] = (runs[-1][0], i + 1, src.distribution)
            else:
                runs.append((i, i + 1, src.distribution))
        return tuple(runs)

    @cached_property
    def kinds(self) -> tuple[str, ...]:
        """Kind of each source, in order."""
        return tuple(s.kind for s in self.sources)

    @cached_property
    def balls(self) -> tuple[tuple[int, int], ...]:
        """Index ranges (first, stop) of the offset vectors bounded by a ball |e| ≤ r (the
        clearances in the ``any`` gap model; empty otherwise), stop exclusive."""
        return tuple((j, j + 3) for j, s in enumerate(self.sources)
                     if s.in_ball and s.axis == _AXES[0])


def catalogue(directions: str = 'any') -> tuple[tuple[str, str, int, str | None], ...]:
    """Every source of the machine as (name, kind, leg, axis), in the order T's columns use,
    for the gap model ``directions`` (:class:`GapModel`: with ``any`` a clearance is the three
    components of its offset vector, else one scalar)."""
    vector_kinds = _VECTOR_KINDS + (BALL_KINDS if directions == 'any' else ())
    out: list[tuple[str, str, int, str | None]] = []
    for kind in KINDS:
        for leg in (1, 2, 3):
            if kind in vector_kinds:
                out.extend((f'{kind}_{leg}_{a}', kind, leg, a) for a in _AXES)
            else:
                out.append((f'{kind}_{leg}', kind, leg, None))
    return tuple(out)


def _positive(key: str, value: Any, *, allow_zero: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value) or value < 0.0 or (value == 0.0 and not allow_zero):
        need = '>= 0' if allow_zero else '> 0'
        raise ConfigError(f'{key} = {excerpt(value)}: must be a finite number {need} (SI: m or '
                          'rad)')
    return float(value)


def parse_tolerance_spec(data: Mapping[str, Any], mech: Mechanism) -> ToleranceSpec:
    """A :class:`ToleranceSpec` from a parsed YAML mapping (see ``config/tolerances.yaml``).

    Keys: ``tolerances`` (source or group name → tolerance, SI; required), ``distributions``
    (kind → 'normal' | 'uniform'), ``requirement`` (``position`` m, ``orientation`` rad),
    ``clearance_direction`` ('any' (default) | 'leg' | 'motion'), ``motion`` (6 numbers: v m/s,
    ω rad/s). More specific names override groups (``u_centre_2_x`` over ``u_centre``).
    Clearances the spec does not name take the mechanism's design clearance (r_a, r_b); other
    unnamed sources are 0. Unknown names, one component of a clearance ball
    (``u_clearance_2_x``), negative or non-finite values raise :class:`ConfigError` naming them.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f'tolerance spec: expected a mapping, got {excerpt(data)}')
    for key in data:
        if key not in _SPEC_KEYS:
            raise ConfigError(
                f'tolerance spec: unknown key {excerpt(key)} (known: {", ".join(_SPEC_KEYS)})')
    tolerances = data.get('tolerances')
    if not isinstance(tolerances, Mapping) or not tolerances:
        raise ConfigError(f'tolerance spec: tolerances = {excerpt(tolerances)}: expected a '
                          'mapping of source names to tolerances (m or rad)')
    gap = _gap(data)
    entries = catalogue(gap.mode)
    values = {name: 0.0 for name, *_ in entries}
    for name, kind, _leg, _axis in entries:
        if kind == 'u_clearance':
            values[name] = mech.joint_clearance_u
        elif kind == 's_clearance':
            values[name] = mech.joint_clearance_s
    # Groups first, then legs, then single coordinates: the most specific name wins.
    for key in sorted(tolerances, key=lambda k: (str(k).count('_'), str(k))):
        matched = [(name, kind) for name, kind, *_ in entries
                   if name == key or name.startswith(f'{key}_')]
        if not isinstance(key, str) or not matched:
            raise ConfigError(f'tolerances: unknown source {excerpt(key)} (groups: '
                              f'{", ".join(KINDS)}; '
                              'or one leg / coordinate, e.g. leg_length_1, u_centre_2_x)')
        if matched[0][1] in BALL_KINDS and key not in {matched[0][1], *(
                f'{matched[0][1]}_{leg}' for leg in (1, 2, 3))}:
            raise ConfigError(f'tolerances: {excerpt(key)} names one component of a clearance; a '
                              'clearance bounds the length of its offset vector: name the '
                              'joint (e.g. u_clearance_2)')
        value = _positive(f'tolerances.{key}', tolerances[key])
        limit = _MAX_ANGLE if matched[0][1] in _ANGLE_KINDS else _MAX_LENGTH
        if value > limit:
            unit = 'rad' if limit == _MAX_ANGLE else 'm'
            raise ConfigError(f'tolerances.{key} = {excerpt(value)}: larger than {limit} {unit}; '
                              'the spec is in SI units (m, rad), not mm or degrees')
        for name, _kind in matched:
            values[name] = value
    distributions = dict(_DEFAULT_DISTRIBUTION)
    given = data.get('distributions') or {}
    if not isinstance(given, Mapping):
        raise ConfigError(f'distributions = {excerpt(given)}: expected a mapping kind -> law')
    for kind, law in given.items():
        if kind not in KINDS:
            raise ConfigError(f'distributions: unknown kind {excerpt(kind)} (known: '
                              f'{", ".join(KINDS)})')
        if law not in DISTRIBUTIONS:
            raise ConfigError(f'distributions.{kind} = {excerpt(law)}: expected normal or uniform')
        distributions[kind] = law
    sources = tuple(ErrorSource(name, kind, leg, axis, values[name], distributions[kind])
                    for name, kind, leg, axis in entries)
    return ToleranceSpec(sources, _requirement(data.get('requirement')), gap)


def _requirement(block: Any) -> Requirement:
    if not isinstance(block, Mapping):
        raise ConfigError(f'requirement = {excerpt(block)}: expected position (m) and '
                          'orientation (rad)')
    for key in block:
        if key not in ('position', 'orientation'):
            raise ConfigError(f'requirement: unknown key {excerpt(key)} (known: position, '
                              'orientation)')
    if 'position' not in block or 'orientation' not in block:
        raise ConfigError(f'requirement = {excerpt(dict(block))}: needs position (m) and '
                          'orientation (rad)')
    return Requirement(_positive('requirement.position', block['position'], allow_zero=False),
                       _positive('requirement.orientation', block['orientation'],
                                 allow_zero=False))


def _gap(data: Mapping[str, Any]) -> GapModel:
    mode = data.get('clearance_direction', GapModel.mode)
    motion = data.get('motion', GapModel.twist)
    try:
        twist = tuple(float(v) for v in motion)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'motion = {excerpt(motion)}: expected 6 numbers (v m/s, ω rad/s)'
                          ) from err
    if len(twist) != 6:
        raise ConfigError(f'motion = {excerpt(motion)}: expected 6 numbers (v m/s, ω rad/s)')
    return GapModel(str(mode), twist)


def load_tolerance_spec(path: str | Path, mech: Mechanism) -> ToleranceSpec:
    """Read and parse a tolerance spec file (YAML); ConfigError names the file and the problem."""
    data = load_parameter_file(path)
    try:
        return parse_tolerance_spec(data, mech)
    except ConfigError as err:
        raise ConfigError(shorten(f'{path}: {err}')) from err


def draw_sources(spec: ToleranceSpec, n: int, rng: np.random.Generator) -> FloatArray:
    """n samples of every source (n, S), m or rad, from each source's law.

    The result is the transposed view of an (S, n) C-ordered array: samples run along the
    contiguous axis, which is what the vectorised closure solve wants. Runs of consecutive
    sources with the same law are drawn in place into their rows. The truncated normal is drawn
    by rejection from ``rng.standard_normal`` (redrawing the 0.27 % beyond 3σ): exact, and far
    faster than ``scipy.stats.truncnorm.rvs`` on this hot path. A clearance ball (``any`` gap
    model, :attr:`ToleranceSpec.balls`) is x·d: x the first component's draw from the law, d
    uniform on the unit sphere (normalised standard normals), so |e| ≤ r.
    """
    unit = draw_laws(spec.bounds, [(a, b, law, _SIGMAS) for a, b, law in spec.law_runs], n,
                     rng)
    if spec.balls:
        heads = np.array([b[0] for b in spec.balls])
        d = rng.standard_normal(size=(heads.size, 3, n))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        unit[heads[:, None] + np.arange(3)] = unit[heads][:, None, :] * d
    drawn: FloatArray = unit.T
    return drawn
