"""Fault injection of the simulated drives: failed encoders, jammed axes, noise bursts and a
motion nobody commanded, set while the driver runs (the ``fault:`` block, dynamic)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import ConfigError
from positioning_cell.parameters import ParameterError, check_fields, setting
from positioning_cell.sim.axes import AXES

BoolArray = NDArray[np.bool_]

# -- fault injection -------------------------------------------------------------------------
def axis_mask(spec: str) -> BoolArray:
    """Axes named in ``spec``: joint names or 0-based indices (JOINT_NAMES order) separated by
    commas or spaces, '' for none. ConfigError names an unknown entry."""
    mask = np.zeros(AXES, dtype=bool)
    for token in spec.replace(',', ' ').split():
        if token in JOINT_NAMES:
            mask[JOINT_NAMES.index(token)] = True
        elif token.isdigit() and int(token) < AXES:
            mask[int(token)] = True
        else:
            raise ConfigError(f'{token!r} is neither a joint name {list(JOINT_NAMES)} nor an '
                              f'axis index 0-{AXES - 1}')
    return mask


@dataclass(frozen=True)
class DriveFaults:
    """Injected faults: ``encoder_dropout`` encoders that freeze (or read NaN in
    ``missing`` mode), ``stuck_axis`` jammed axes (joint names or indices 0-5, '' for none),
    and ``noise_burst`` [σ scale ≥ 1, duration s]: the encoder noise times the scale for that
    long after it was set."""

    encoder_dropout: str = setting('', 'failed encoders: joint names or indices 0-5',
                                   dynamic=True)
    encoder_dropout_mode: str = setting('freeze', 'a failed encoder freezes or reads NaN',
                                        choices=('freeze', 'missing'), dynamic=True)
    stuck_axis: str = setting('', 'jammed axes: joint names or indices 0-5', dynamic=True)
    noise_burst: tuple[float, float] = setting((1.0, 0.0), '[noise sigma scale >= 1, duration '
                                               's], starts when set', dynamic=True)
    uncommanded_motion: tuple[float, float] = setting(
        (0.0, 0.0), '[axis index 0-5, distance m or rad]: when set, the drives move that axis '
        'by that distance on their own (a stale motion block nobody sent), at a fifth of its '
        'speed limit; any command or stop replaces it', 'index, m or rad', dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ('encoder_dropout', 'stuck_axis'):
            try:
                axis_mask(getattr(self, name))
            except ConfigError as err:
                raise ParameterError(name, getattr(self, name), str(err)) from err
        scale, duration = self.noise_burst
        if scale < 1.0 or duration < 0.0:
            raise ParameterError('noise_burst', list(self.noise_burst),
                                 'expected [scale >= 1, duration s >= 0]')
        axis, distance = self.uncommanded_motion
        if axis not in range(AXES) or abs(distance) > 0.01:
            raise ParameterError('uncommanded_motion', list(self.uncommanded_motion),
                                 f'expected [axis index 0-{AXES - 1}, distance within '
                                 '+-0.01 m or rad]')

    @cached_property
    def dropout(self) -> BoolArray:
        """Failed encoders (6,)."""
        return axis_mask(self.encoder_dropout)

    @cached_property
    def stuck(self) -> BoolArray:
        """Jammed axes (6,)."""
        return axis_mask(self.stuck_axis)

    @property
    def missing(self) -> bool:
        """Failed encoders read NaN (else they freeze)."""
        return self.encoder_dropout_mode == 'missing'

    def noise_scale(self, since_burst: float) -> float:
        """Noise σ scale ``since_burst`` s after the burst was set."""
        scale, duration = self.noise_burst
        return scale if 0.0 <= since_burst < duration else 1.0
