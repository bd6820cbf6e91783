"""Pose accuracy of the cell: measured vs commanded pose, settle detection, ISO 9283 figures,
tolerance verdicts, the tracker against the truth, and the monitor that applies them all.
Pure numpy/scipy over arrays of samples; no ROS.

- :mod:`.settle`: settle windows, visits, the batch and streaming accumulators;
- :mod:`.iso9283`: ISO 9283:1998 AP and RP of a commanded pose;
- :mod:`.verdicts`: tolerances and verdicts;
- :mod:`.tracker_errors`: measured minus true pose over paired stamps;
- :mod:`.monitor`: the accuracy monitor's rules (node and offline replay).
"""

from positioning_cell.accuracy.iso9283 import (
    PoseFigures,
    iso9283,
    orientation_angles,
    wrap_angle,
)
from positioning_cell.accuracy.monitor import (
    Ignored,
    Measured,
    Monitor,
    MonitorSettings,
    TrackerErrorSettings,
)
from positioning_cell.accuracy.settle import (
    AccuracyAccumulator,
    AccuracyResult,
    PoseKeys,
    SampleUpdate,
    SettleSettings,
    Visit,
    analyse,
    figures_by_pose,
    measurement_error,
    settled_visits,
    stamp_seconds,
)
from positioning_cell.accuracy.tracker_errors import (
    ErrorStatistics,
    TrackerErrorAccumulator,
    error_statistics,
    pair_by_stamp,
    tracker_errors,
)
from positioning_cell.accuracy.verdicts import (
    ORIENTATION_TOLERANCE,
    POSITION_TOLERANCE,
    Tolerances,
    Verdict,
    judge,
    judge_visit,
)
from positioning_cell.core.poses import EULER_SEQUENCE

__all__ = [
    'EULER_SEQUENCE',
    'ORIENTATION_TOLERANCE',
    'POSITION_TOLERANCE',
    'AccuracyAccumulator',
    'AccuracyResult',
    'ErrorStatistics',
    'Ignored',
    'Measured',
    'Monitor',
    'MonitorSettings',
    'PoseFigures',
    'PoseKeys',
    'SampleUpdate',
    'SettleSettings',
    'Tolerances',
    'TrackerErrorAccumulator',
    'TrackerErrorSettings',
    'Verdict',
    'Visit',
    'analyse',
    'error_statistics',
    'figures_by_pose',
    'iso9283',
    'judge',
    'judge_visit',
    'measurement_error',
    'orientation_angles',
    'pair_by_stamp',
    'settled_visits',
    'stamp_seconds',
    'tracker_errors',
    'wrap_angle',
]
