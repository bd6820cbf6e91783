"""The ``live_view`` node's settings: where its Foxglove WebSocket server listens, how often it
sends, the error arrow's magnification and the frame of its deviation channel, and whether it
shows one positioner or a coordinated cell's panel."""

from __future__ import annotations

from dataclasses import dataclass

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.watch.deviation import WATCH_FRAMES

#: What the live view can show.
LIVE_VIEWS = ('positioner', 'panel')


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
    view: str = setting('positioner', "what it shows: 'positioner' (one positioner; a set of "
                        "a coordinated cell with -r __ns:=/<name>) or 'panel' (a coordinated "
                        "cell: the panel, each positioner's base and the internal forces)",
                        choices=LIVE_VIEWS)
    force_scale: float = setting(1e-3, "the panel view's internal force arrows: length per "
                                 'newton', 'm/N', low=0.0, low_open=True, high=1.0)

    def __post_init__(self) -> None:
        check_fields(self)
