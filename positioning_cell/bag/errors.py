"""The bag subpackage's one exception type."""

from __future__ import annotations

from pathlib import Path

from positioning_cell.errors import PositioningError


class BagError(PositioningError):
    """A bag cannot be written, read or recovered: ``path`` names it, ``reason`` says why.

    Raised before anything is changed on disk whenever the problem is detectable up front
    (an existing output, a file that is not MCAP, a metadata.yaml that does not parse).
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f'{path}: {reason}')
        self.path = Path(path)
        self.reason = reason
