"""The parameters of the recorder and the player nodes (config/cell.yaml ``recorder`` and
``bag_player`` sections; read-only)."""

from __future__ import annotations

from dataclasses import dataclass

from positioning_cell.bag.writer import MAX_CHUNK_BYTES
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.recording.disk import DiskSettings


@dataclass(frozen=True)
class SplitSettings:
    """When the recorder starts a new ``.mcap`` file (0: never)."""

    max_bytes: int = setting(0, 'new .mcap file at this size', 'bytes', low=0, high=2**62)
    max_duration_s: float = setting(0.0, 'new .mcap file after this span of receive time', 's',
                                    low=0.0, high=1e9)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class RecorderSettings:
    """Every parameter of the ``recorder`` node."""

    output: str = setting('', 'bag directory to create (never overwritten); empty: '
                          'runs/<UTC timestamp>/bag under the working directory')
    topics: tuple[str, ...] = setting((), 'topics to record (absolute names); with '
                                      'topic_pattern empty too: every topic of the cell')
    topic_pattern: str = setting('', 'regular expression (full match) of further topics, e.g. '
                                 '"/sim/.*"')
    compression: str = setting('none', 'MCAP chunk compression', choices=('none', 'zstd'))
    chunk_bytes: int = setting(65536, 'MCAP chunk size', 'bytes', low=1024,
                               high=MAX_CHUNK_BYTES)
    flush_period_s: float = setting(0.5, 'chunks reach the disk at least this often (bounds '
                                    'what a SIGKILL loses)', 's', low=0.05, high=60.0)
    discovery_period_s: float = setting(0.5, 'graph polling period for new topics', 's',
                                        low=0.05, high=60.0)
    queue_depth: int = setting(0, 'subscription history per topic (0: keep all)', 'messages',
                               low=0, high=1_000_000)
    description_file: str = setting('', 'the run\'s description (run_cell and cell up write '
                                    'it): stored in the bag with the files it names; empty: '
                                    'none')
    split: SplitSettings = group(SplitSettings, 'file splits')
    disk: DiskSettings = group(DiskSettings, 'free space of the bag\'s filesystem (WARN margins)')

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class PlayerSettings:
    """Every parameter of the ``bag_player`` node."""

    bag: str = setting('', 'bag directory to play (required)')
    rate: float = setting(1.0, 'replay speed factor (2 = twice as fast)', low=0.01, high=100.0)
    start_offset_s: float = setting(0.0, 'start this far into the bag, s of bag time', 's',
                                    low=0.0, high=1e9)
    loop: bool = setting(False, 'start over at the end')
    topics: tuple[str, ...] = setting((), 'topics to play; empty: every topic of the bag')
    queue_depth: int = setting(1000, 'publisher history of streamed topics', 'messages', low=1,
                               high=1_000_000)
    wait_for_subscribers_s: float = setting(5.0, 'wait up to this long for every topic to have '
                                            'a subscriber before playing', 's', low=0.0,
                                            high=600.0)

    def __post_init__(self) -> None:
        check_fields(self)
