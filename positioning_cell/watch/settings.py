"""The ``live_view`` node's settings: where its Foxglove WebSocket server listens, how often it
sends, the error arrow's magnification and the frame of its deviation channel."""

from __future__ import annotations

from dataclasses import dataclass

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.watch.deviation import WATCH_FRAMES


@dataclass(frozen=True)
class LiveViewSettings:
    """Every parameter of the ``live_view`` node (read-only: restart to change them)."""

    mechanism: Mechanism = group(Mechanism, 'the nominal machine the scene draws')
    host: str = setting('127.0.0.1', 'address the WebSocket server binds (loopback by '
                        'default; 0.0.0.0 serves every interface)')
    port: int = setting(8765, 'WebSocket port (0: any free port, logged at start)', low=0,
                        high=65535)
    rate_hz: float = setting(20.0, 'most messages per second on each channel (one per tracker '
                             'measurement up to this rate)', 'Hz', low=0.0, low_open=True,
                             high=200.0)
    magnification: float = setting(1000.0, 'scale of the error arrow and the tolerance '
                                   'sphere in the 3-D scene', low=0.0, low_open=True,
                                   high=1e6)
    frame: str = setting('base', 'frame of the deviation channel', choices=WATCH_FRAMES)

    def __post_init__(self) -> None:
        check_fields(self)
