"""Recording and replaying the cell's topics as rosbag2 MCAP bags (pure library, no rclpy).

- :class:`BagWriter`: serialized messages → ``<bag>/<bag>_N.mcap`` + ``metadata.yaml``, small
  chunks flushed on demand, optional zstd chunk compression, size / duration splits.
- :class:`BagReader`: a bag read back through rosbags, raw (for replay) or decoded (analysis).
- :func:`recover_bag`: a bag whose recorder was killed → valid, indexed files + metadata.
- :class:`PlaybackTiming`, :func:`play`: replay with the recorded timing.
"""

from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import (
    FileSummary,
    TopicMeta,
    playback_qos,
    recording_qos,
)
from positioning_cell.bag.playback import PlaybackTiming, play
from positioning_cell.bag.reader import BagMessage, BagReader, RawMessage, TopicInfo
from positioning_cell.bag.recovery import FileRecovery, RecoveryReport, recover_bag
from positioning_cell.bag.settings import PlayerSettings, RecorderSettings, SplitSettings
from positioning_cell.bag.topics import TopicSelection
from positioning_cell.bag.writer import BagWriter, message_definition

__all__ = [
    'BagError',
    'BagMessage',
    'BagReader',
    'BagWriter',
    'FileRecovery',
    'FileSummary',
    'PlaybackTiming',
    'PlayerSettings',
    'RawMessage',
    'RecorderSettings',
    'RecoveryReport',
    'SplitSettings',
    'TopicInfo',
    'TopicMeta',
    'TopicSelection',
    'message_definition',
    'play',
    'playback_qos',
    'recording_qos',
    'recover_bag',
]
