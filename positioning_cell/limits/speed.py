"""The operator's speeds and accelerations of a move: set within configured maxima (a value
above its maximum is refused, never clamped), scaled for one move, and turned into the
:class:`positioning_cell.moves.trajectory.MotionLimits` a move is planned with."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields

from positioning_cell.core.poses import as_number
from positioning_cell.errors import InputError
from positioning_cell.moves.trajectory import MotionLimits
from positioning_cell.parameters import ParameterError

_UNITS = {
    'linear_speed': 'm/s',
    'angular_speed': 'rad/s',
    'linear_acceleration': 'm/s^2',
    'angular_acceleration': 'rad/s^2',
}


@dataclass(frozen=True)
class Speeds:
    """Cartesian speeds and accelerations of a move: linear m/s, angular rad/s, linear m/s²,
    angular rad/s². Any float is held as given (a request may carry 0 for "keep", or a bad
    value to be refused by :func:`set_speeds`); InputError only for what is not a number."""

    linear_speed: float
    angular_speed: float
    linear_acceleration: float
    angular_acceleration: float

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, as_number(getattr(self, f.name), f.name))

    @classmethod
    def of(cls, limits: MotionLimits) -> Speeds:
        """The speeds and accelerations of a MotionLimits."""
        return cls(limits.linear_speed, limits.angular_speed, limits.linear_acceleration,
                   limits.angular_acceleration)

    @classmethod
    def keep(cls) -> Speeds:
        """A request that changes nothing (every field 0)."""
        return cls(0.0, 0.0, 0.0, 0.0)


def _text(name: str, value: float) -> str:
    return f'{value:g} {_UNITS[name]}'


def _require_positive(speeds: Speeds, what: str) -> None:
    for f in fields(speeds):
        value = getattr(speeds, f.name)
        if not (math.isfinite(value) and value > 0.0):
            raise InputError(f'{what}.{f.name} = {value!r}: must be a finite number > 0 '
                             f'{_UNITS[f.name]}')


def set_speeds(current: Speeds, maxima: Speeds, request: Speeds) -> Speeds:
    """The speeds after ``request``: a field of 0 keeps the current value, any other must be
    finite, > 0 and <= its maximum. Everything refused is named in one InputError (field,
    value, maximum) and nothing changes; a value is never clamped. A kept current value above
    its (lowered) maximum is refused too: the result is always within ``maxima``. InputError
    also when ``current`` or ``maxima`` hold a value that is not finite and > 0."""
    _require_positive(maxima, 'maxima')
    _require_positive(current, 'current')
    values: dict[str, float] = {}
    problems = []
    for f in fields(request):
        name = f.name
        asked, limit = getattr(request, name), getattr(maxima, name)
        value = getattr(current, name) if asked == 0.0 else asked
        if math.isnan(value) or math.isinf(value):
            problems.append(f'{name} = {value!r}: not a finite number')
        elif value < 0.0:
            problems.append(f'{name} = {_text(name, value)}: negative (0 keeps the current '
                            f'{_text(name, getattr(current, name))})')
        elif value > limit:
            which = 'the current ' if asked == 0.0 else ''
            problems.append(f'{name} = {which}{_text(name, value)}: above the maximum '
                            f'{_text(name, limit)}')
        values[name] = value
    if problems:
        raise InputError('speeds refused: ' + '; '.join(problems))
    return Speeds(**values)


def scaled(speeds: Speeds, scale: float) -> Speeds:
    """The speeds of a move at ``scale`` in (0, 1] of ``speeds``: speeds times ``scale``,
    accelerations times the square of ``scale`` (the same move, played 1/scale times slower);
    InputError outside (0, 1] or not finite."""
    scale = as_number(scale, 'speed scale')
    if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
        raise InputError(f'speed scale = {scale!r}: must be in (0, 1]')
    return Speeds(speeds.linear_speed * scale, speeds.angular_speed * scale,
                  speeds.linear_acceleration * scale**2,
                  speeds.angular_acceleration * scale**2)


def motion_limits(base: MotionLimits, speeds: Speeds) -> MotionLimits:
    """The MotionLimits a move with ``speeds`` is planned with: ``base`` with its four fields
    (linear_speed, linear_acceleration, angular_speed, angular_acceleration, which correspond
    one to one) replaced. InputError naming the field when a value is outside what
    MotionLimits accepts (e.g. below its 1e-5 floor)."""
    try:
        return dataclasses.replace(
            base, linear_speed=speeds.linear_speed, angular_speed=speeds.angular_speed,
            linear_acceleration=speeds.linear_acceleration,
            angular_acceleration=speeds.angular_acceleration)
    except ParameterError as err:
        raise InputError(f'motion limits refused: {err}') from err
