"""Exception types of the library: one small type per kind of failure."""

from __future__ import annotations


class PositioningError(Exception):
    """Base class of every error the library raises on purpose."""


class InputError(PositioningError, ValueError):
    """A malformed argument: wrong shape, NaN or infinite, a non-unit quaternion, a bad frame."""


class ConfigError(PositioningError, ValueError):
    """A parameter (file or dict) is missing, of the wrong type or out of its range."""


class ConvergenceError(PositioningError):
    """An iterative solver (forward kinematics, compensation) did not converge."""
