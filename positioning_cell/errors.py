"""Exception types of the library: one small type per kind of failure."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from positioning_cell.core.limits import LimitReport


class PositioningError(Exception):
    """Base class of every error the library raises on purpose."""


class InputError(PositioningError, ValueError):
    """A malformed argument: wrong shape, NaN or infinite, a non-unit quaternion, a bad frame."""


class ConfigError(PositioningError, ValueError):
    """A parameter (file or dict) is missing, of the wrong type or out of its range."""


class LimitError(PositioningError):
    """A pose or path violates a joint, stroke, collision or singularity limit."""

    def __init__(self, report: LimitReport) -> None:
        super().__init__(report.message())
        self.report = report


class ConvergenceError(PositioningError):
    """An iterative solver (forward kinematics, compensation) did not converge."""
