"""Geometry and joint limits of the 3-UPS positioner (seed 000, Table 1;
docs/conventions/kinematics.md).

Frames: ``base`` (origin at the centre of the base U-joint circle, z toward the platform) and
``platform`` (origin at the centre of the spherical-joint circle, z along the platform normal).
All values SI: metres and radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import names
from positioning_cell.config import flatten
from positioning_cell.parameters import (
    ParameterError,
    block,
    check_fields,
    parse,
    setting,
    to_params,
)

FloatArray = NDArray[np.float64]

#: Leg azimuths γ_i = 90° + 120°·(i−1).
LEG_AZIMUTHS = (math.pi / 2, math.pi / 2 + 2 * math.pi / 3, math.pi / 2 + 4 * math.pi / 3)

#: Joint names on the wire, kinematics.md order (declared in :mod:`positioning_cell.names`).
JOINT_NAMES = names.JOINT_NAMES
PASSIVE_JOINT_NAMES = ('leg1_phi', 'leg2_phi', 'leg3_phi')

_ZERO_OFFSETS = ((0.0, 0.0, 0.0),) * 3

#: The parameters of the machine's geometry on every node that models it
#: (``mechanism.base_radius``, ...): the prefix another program reads them by.
MECHANISM_PREFIX = 'mechanism.'


@dataclass(frozen=True)
class Mechanism:
    """The 3-UPS positioner: nominal geometry, optional joint-centre offsets and joint limits.

    Lengths in m, angles in rad. ``base_offsets`` (base frame) and ``platform_offsets``
    (platform frame) displace the U-joint centres A_i and the S-joint centres b_i from their
    nominal circle positions: geometric errors of a real machine, or the exact vector
    clearance model (``positioning_cell.clearance``). They are zero for the nominal machine.
    Parameters: the ``mechanism:`` block of config/cell.yaml (shared by every node).
    """

    base_radius: float = setting(0.100, 'R_A, radius of the U-joint circle', 'm', low=0.0,
                                 low_open=True)
    platform_radius: float = setting(0.060, 'R_B, radius of the S-joint circle', 'm', low=0.0,
                                     low_open=True)
    length_min: float = setting(0.180, 'shortest leg (stroke)', 'm', low=0.0, low_open=True)
    length_max: float = setting(0.220, 'longest leg (stroke)', 'm', low=0.0, low_open=True)
    home_length: float = setting(0.200, 'l0, leg length at home', 'm', low=0.0, low_open=True)
    phi_min: float = setting(-math.pi / 4, 'first (passive) U angle, lower limit', 'rad',
                             low=-math.pi / 2, high=math.pi / 2, low_open=True, high_open=True)
    phi_max: float = setting(math.pi / 4, 'first (passive) U angle, upper limit', 'rad',
                             low=-math.pi / 2, high=math.pi / 2, low_open=True, high_open=True)
    theta_min: float = setting(-math.pi / 4, 'second (actuated) U angle, lower limit', 'rad',
                               low=-math.pi / 2, high=math.pi / 2, low_open=True,
                               high_open=True)
    theta_max: float = setting(math.pi / 4, 'second (actuated) U angle, upper limit', 'rad',
                               low=-math.pi / 2, high=math.pi / 2, low_open=True,
                               high_open=True)
    tilt_max: float = setting(math.pi / 3, 'spherical-joint tilt limit', 'rad', low=0.0,
                              high=math.pi / 2, low_open=True, high_open=True)
    min_leg_distance: float = setting(0.030, 'closest approach of two leg axes', 'm', low=0.0)
    min_conditioning: float = setting(0.02, 'singularity margin: smallest reciprocal condition '
                                      'number of the inverse Jacobian', low=0.0, high=1.0,
                                      high_open=True)
    joint_clearance_u: float = setting(0.16e-3, 'r_a, U-joint clearance (design value)', 'm',
                                       low=0.0)
    joint_clearance_s: float = setting(0.16e-3, 'r_b, S-joint clearance (design value)', 'm',
                                       low=0.0)
    base_offsets: tuple[tuple[float, float, float], ...] = setting(
        _ZERO_OFFSETS, 'U-joint centre offsets from the nominal circle, 3 legs x (x, y, z), '
        'base frame', 'm', length=9)
    platform_offsets: tuple[tuple[float, float, float], ...] = setting(
        _ZERO_OFFSETS, 'S-joint centre offsets from the nominal circle, 3 legs x (x, y, z), '
        'platform frame', 'm', length=9)

    def __post_init__(self) -> None:
        check_fields(self)
        _validate(self)

    # -- construction -------------------------------------------------------------------
    @classmethod
    def default(cls) -> Mechanism:
        """The machine of seed 000, Table 1."""
        return cls()

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Mechanism:
        """From the ``mechanism:`` block of config/cell.yaml: nested or dotted keys relative to
        the block (``base_radius``), or the whole block under ``mechanism``. Unknown keys and
        bad values raise ConfigError naming the key; missing keys keep the seed 000 values."""
        flat = flatten(params)
        if any(k.startswith(MECHANISM_PREFIX) for k in flat):
            flat = block(flat, MECHANISM_PREFIX.rstrip('.'))
        return parse(cls, flat, MECHANISM_PREFIX)

    def to_params(self) -> dict[str, Any]:
        """The ``mechanism:`` block as a nested dict (inverse of :meth:`from_params`)."""
        return to_params(self)

    def with_offsets(self, base_offsets: FloatArray | None = None,
                     platform_offsets: FloatArray | None = None) -> Mechanism:
        """A copy with the joint-centre offsets (3, 3) replaced (m; base / platform frame)."""
        kwargs: dict[str, Any] = {}
        if base_offsets is not None:
            kwargs['base_offsets'] = np.asarray(base_offsets, dtype=float)
        if platform_offsets is not None:
            kwargs['platform_offsets'] = np.asarray(platform_offsets, dtype=float)
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


def _validate(m: Mechanism) -> None:
    """The rules between fields (each field's own range is in its declaration)."""
    if m.length_max <= m.length_min:
        raise ParameterError('length_max', m.length_max,
                             f'must exceed length_min = {m.length_min!r} m')
    if not m.length_min <= m.home_length <= m.length_max:
        raise ParameterError('home_length', m.home_length,
                             f'must lie in [{m.length_min}, {m.length_max}] m')
    if m.home_length <= abs(m.base_radius - m.platform_radius):
        raise ParameterError('home_length', m.home_length,
                             'must exceed |base_radius - platform_radius|')
    for lo, hi in (('phi_min', 'phi_max'), ('theta_min', 'theta_max')):
        if not getattr(m, lo) < getattr(m, hi):
            raise ParameterError(hi, getattr(m, hi), f'must exceed {lo} = {getattr(m, lo)!r} rad')
