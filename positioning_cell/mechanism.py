"""Geometry and joint limits of the 3-UPS positioner (seed 000, Table 1; design/kinematics.md).

Frames: ``base`` (origin at the centre of the base U-joint circle, z toward the platform) and
``platform`` (origin at the centre of the spherical-joint circle, z along the platform normal).
All values SI: metres and radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import ConfigError

FloatArray = NDArray[np.float64]

#: Leg azimuths γ_i = 90° + 120°·(i−1).
LEG_AZIMUTHS = (math.pi / 2, math.pi / 2 + 2 * math.pi / 3, math.pi / 2 + 4 * math.pi / 3)

#: Joint names on the wire, kinematics.md order.
JOINT_NAMES = (
    'leg1_length', 'leg2_length', 'leg3_length', 'leg1_theta', 'leg2_theta', 'leg3_theta',
)
PASSIVE_JOINT_NAMES = ('leg1_phi', 'leg2_phi', 'leg3_phi')

_ZERO_OFFSETS = ((0.0, 0.0, 0.0),) * 3


@dataclass(frozen=True)
class Mechanism:
    """The 3-UPS positioner: nominal geometry, optional joint-centre offsets and joint limits.

    Lengths in m, angles in rad. ``base_offsets`` (base frame) and ``platform_offsets``
    (platform frame) displace the U-joint centres A_i and the S-joint centres b_i from their
    nominal circle positions: geometric errors of a real machine, or the exact vector
    clearance model (``positioning_cell.clearance``). They are zero for the nominal machine.
    """

    base_radius: float = 0.100
    platform_radius: float = 0.060
    length_min: float = 0.180
    length_max: float = 0.220
    home_length: float = 0.200
    phi_min: float = -math.pi / 4
    phi_max: float = math.pi / 4
    theta_min: float = -math.pi / 4
    theta_max: float = math.pi / 4
    tilt_max: float = math.pi / 3
    min_leg_distance: float = 0.030
    min_conditioning: float = 0.02
    joint_clearance_u: float = 0.16e-3
    joint_clearance_s: float = 0.16e-3
    base_offsets: tuple[tuple[float, float, float], ...] = field(default=_ZERO_OFFSETS)
    platform_offsets: tuple[tuple[float, float, float], ...] = field(default=_ZERO_OFFSETS)

    def __post_init__(self) -> None:
        _validate(self)

    # -- construction -------------------------------------------------------------------
    @classmethod
    def default(cls) -> Mechanism:
        """The machine of seed 000, Table 1."""
        return cls()

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Mechanism:
        """Build from the ``mechanism:`` block of ``config/cell.yaml``.

        Accepts the nested dict a YAML loader gives or the flat dotted keys rclpy gives
        (``mechanism.base_radius``); unknown keys and bad values raise :class:`ConfigError`
        naming the key and the value. Missing keys keep the seed 000 defaults.
        """
        flat = {k.removeprefix('mechanism.'): v for k, v in params.items()}
        if isinstance(flat.get('mechanism'), Mapping):
            flat = dict(flat.pop('mechanism'))
        names = {f.name: f for f in fields(cls)}
        kwargs: dict[str, Any] = {}
        for key, value in flat.items():
            if key not in names:
                raise ConfigError(
                    f'mechanism: unknown parameter {key!r} (known: {", ".join(sorted(names))})')
            if key in ('base_offsets', 'platform_offsets'):
                kwargs[key] = _offsets_from(key, value)
            else:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ConfigError(f'mechanism.{key}: expected a number, got {value!r}')
                kwargs[key] = float(value)
        return cls(**kwargs)

    def to_params(self) -> dict[str, Any]:
        """The ``mechanism:`` block as a nested dict (inverse of :meth:`from_params`)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = [list(v) for v in value] if f.name.endswith('_offsets') else value
        return out

    def with_offsets(self, base_offsets: FloatArray | None = None,
                     platform_offsets: FloatArray | None = None) -> Mechanism:
        """A copy with the joint-centre offsets (3, 3) replaced (m; base / platform frame)."""
        kwargs: dict[str, Any] = {}
        if base_offsets is not None:
            kwargs['base_offsets'] = _offsets_from('base_offsets', np.asarray(base_offsets))
        if platform_offsets is not None:
            kwargs['platform_offsets'] = _offsets_from(
                'platform_offsets', np.asarray(platform_offsets))
        return replace(self, **kwargs)

    # -- derived geometry (read-only arrays) ----------------------------------------------
    @cached_property
    def radial(self) -> FloatArray:
        """e_r,i as rows (3, 3)."""
        g = np.asarray(LEG_AZIMUTHS)
        return _readonly(np.stack([np.cos(g), np.sin(g), np.zeros(3)], axis=1))

    @cached_property
    def tangential(self) -> FloatArray:
        """e_t,i as rows (3, 3): the first U axis of each leg."""
        g = np.asarray(LEG_AZIMUTHS)
        return _readonly(np.stack([-np.sin(g), np.cos(g), np.zeros(3)], axis=1))

    @cached_property
    def base_joints(self) -> FloatArray:
        """U-joint centres A_i in the base frame, rows (3, 3), m."""
        return _readonly(self.base_radius * self.radial + np.asarray(self.base_offsets))

    @cached_property
    def platform_joints(self) -> FloatArray:
        """S-joint centres b_i in the platform frame, rows (3, 3), m."""
        return _readonly(self.platform_radius * self.radial + np.asarray(self.platform_offsets))

    @cached_property
    def home_height(self) -> float:
        """h0 = sqrt(l0² − (R_A − R_B)²): platform height at home, m."""
        return math.sqrt(self.home_length**2 - (self.base_radius - self.platform_radius) ** 2)

    @property
    def home_position(self) -> FloatArray:
        """Home position (0, 0, h0) in the base frame, m."""
        return np.array([0.0, 0.0, self.home_height])

    @property
    def home_quaternion(self) -> FloatArray:
        """Home orientation (identity) as x, y, z, w."""
        return np.array([0.0, 0.0, 0.0, 1.0])

    @property
    def characteristic_length(self) -> float:
        """Length that makes rotations commensurate with translations (R_B), m."""
        return self.platform_radius


def _readonly(a: FloatArray) -> FloatArray:
    a.setflags(write=False)
    return a


def _offsets_from(key: str, value: Any) -> tuple[tuple[float, float, float], ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'mechanism.{key}: expected 3 x 3 numbers (m), got {value!r}') from err
    if arr.size == 9:
        arr = arr.reshape(3, 3)
    if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        raise ConfigError(f'mechanism.{key}: expected 3 x 3 finite numbers (m), got {value!r}')
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in arr)


def _validate(m: Mechanism) -> None:
    def bad(key: str, why: str) -> ConfigError:
        return ConfigError(f'mechanism.{key} = {getattr(m, key)!r}: {why}')

    for f in fields(m):
        v = getattr(m, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            raise bad(f.name, 'must be finite')
    for key in ('base_radius', 'platform_radius', 'length_min', 'home_length'):
        if getattr(m, key) <= 0.0:
            raise bad(key, 'must be > 0 m')
    for key in ('min_leg_distance', 'joint_clearance_u', 'joint_clearance_s'):
        if getattr(m, key) < 0.0:
            raise bad(key, 'must be >= 0 m')
    if m.length_max <= m.length_min:
        raise bad('length_max', f'must exceed length_min = {m.length_min!r} m')
    if not m.length_min <= m.home_length <= m.length_max:
        raise bad('home_length', f'must lie in [{m.length_min}, {m.length_max}] m')
    if m.home_length <= abs(m.base_radius - m.platform_radius):
        raise bad('home_length', 'must exceed |base_radius - platform_radius|')
    for lo, hi in (('phi_min', 'phi_max'), ('theta_min', 'theta_max')):
        if not -math.pi / 2 < getattr(m, lo) < getattr(m, hi) < math.pi / 2:
            raise bad(hi, f'need -pi/2 < {lo} < {hi} < pi/2 rad')
    if not 0.0 < m.tilt_max < math.pi / 2:
        raise bad('tilt_max', 'must lie in (0, pi/2) rad')
    if not 0.0 <= m.min_conditioning < 1.0:
        raise bad('min_conditioning', 'must lie in [0, 1)')
