"""Recording and replaying the cell's topics as rosbag2 MCAP bags (pure library, no rclpy).

- :class:`BagWriter`: serialized messages → ``<bag>/<bag>_N.mcap`` + ``metadata.yaml``, small
  chunks flushed on demand, optional zstd chunk compression, size / duration splits.
- :class:`BagReader`: a bag read back through rosbags, raw or decoded.
- :class:`IndexedBag`: chosen topics of an MCAP bag read through its index in blocks, in
  bounded memory, decoded vectorised (:mod:`positioning_cell.bag.cdr`; types with sequences
  per layout, :mod:`positioning_cell.bag.cdr_sequences`); a file without the
  index this needs (any valid MCAP layout) is scanned when it is opened
  (:mod:`positioning_cell.bag.file_index`); IndexedReadError when a file cannot be read as
  it is (truncated, damaged).
- :func:`open_bag`: a bag open for reading whatever its storage (MCAP: IndexedBag; sqlite3:
  BagReader), as a :class:`MessageSource`: what the player and ``calibrate_cell --from-bag``
  read.
- :func:`verify_bag`: every storage file checked (MCAP magic, chunk and data-section CRCs,
  records): the corrupt chunks with the log times and messages they covered.
- :func:`recover_bag`: a bag whose recorder was killed, or with corrupt chunks → valid,
  indexed files (the sound chunks) + metadata.
- :class:`PlaybackTiming`, :func:`play`: replay with the recorded timing.
"""

from positioning_cell.bag.errors import (
    BagError,
    DamagedBagError,
    IndexedReadError,
    UnindexedBagError,
    UnsupportedBagError,
)
from positioning_cell.bag.indexed import IndexedBag
from positioning_cell.bag.metadata import (
    FileSummary,
    TopicMeta,
    playback_qos,
    recording_qos,
)
from positioning_cell.bag.opening import MessageSource, open_bag
from positioning_cell.bag.playback import PlaybackTiming, play
from positioning_cell.bag.reader import BagMessage, BagReader, RawMessage, TopicInfo
from positioning_cell.bag.recovery import FileRecovery, RecoveryReport, recover_bag
from positioning_cell.bag.settings import PlayerSettings, RecorderSettings, SplitSettings
from positioning_cell.bag.topics import TopicSelection
from positioning_cell.bag.verify import BagCheck, DamagedChunk, FileCheck, verify_bag, verify_file
from positioning_cell.bag.writer import BagWriter, message_definition

__all__ = [
    'BagCheck',
    'BagError',
    'BagMessage',
    'BagReader',
    'BagWriter',
    'DamagedBagError',
    'DamagedChunk',
    'FileCheck',
    'FileRecovery',
    'FileSummary',
    'IndexedBag',
    'IndexedReadError',
    'MessageSource',
    'PlaybackTiming',
    'PlayerSettings',
    'RawMessage',
    'RecorderSettings',
    'RecoveryReport',
    'SplitSettings',
    'TopicInfo',
    'TopicMeta',
    'TopicSelection',
    'UnindexedBagError',
    'UnsupportedBagError',
    'message_definition',
    'open_bag',
    'play',
    'playback_qos',
    'recording_qos',
    'recover_bag',
    'verify_bag',
    'verify_file',
]
