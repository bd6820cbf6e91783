"""The recorder's health as the cell sees it (pure library, no ROS, no bag files).

- :mod:`.disk`: free space of the bag's filesystem, the rate it falls at, and the recorder's
  margins (WARN below them).
- :mod:`.status`: the recorder's status on /diagnostics (``recorder``): what it publishes, and
  the one rule by which the accuracy monitor, ``cell watch`` and the live view read it
  ("the recorder silent, failed or stopped → recording stopped").
"""

from positioning_cell.recording.disk import (
    RATE_WINDOW_S,
    DiskReport,
    DiskSettings,
    FreeSpace,
    free_bytes,
    human_bytes,
)
from positioning_cell.recording.status import (
    SILENT_AFTER_S,
    STATUS_PERIOD_S,
    RecorderReport,
    RecorderState,
    RecorderStatus,
    Recording,
    recorder_status,
    recording,
)

__all__ = [
    'RATE_WINDOW_S',
    'SILENT_AFTER_S',
    'STATUS_PERIOD_S',
    'DiskReport',
    'DiskSettings',
    'FreeSpace',
    'RecorderReport',
    'RecorderState',
    'RecorderStatus',
    'Recording',
    'free_bytes',
    'human_bytes',
    'recorder_status',
    'recording',
]
