"""Pose accuracy of the cell: measured vs commanded pose, settle detection, ISO 9283 figures,
tolerance verdicts, the tracker against the truth, and the monitor that applies them all.
Pure numpy/scipy over arrays of samples; no ROS.

- :mod:`.settle`: settle windows, visits, the batch and streaming accumulators;
- :mod:`.iso9283`: ISO 9283:1998 AP, RP and vAP of a commanded pose, AD and RD between two;
- :mod:`.figure_uncertainty`: the expanded uncertainty of those figures;
- :mod:`.iso230_2_uncertainty`: the expanded uncertainty of the ISO 230-2 axis figures;
- :mod:`.stabilisation`: ISO 9283 pose stabilisation time and overshoot of a visit, with U;
- :mod:`.drift`: ISO 9283 drift of a pose's accuracy and repeatability over a run, with U;
- :mod:`.path`: ISO 9283 path accuracy and repeatability of straight-line moves, with U;
- :mod:`.path_velocity`: ISO 9283 path velocity accuracy, repeatability, fluctuation, with U;
- :mod:`.verdicts`: tolerances and verdicts;
- :mod:`.decisions`: ISO 14253-1 decisions with the measurement's expanded uncertainty;
- :mod:`.tracker_errors`: measured minus true pose over paired stamps;
- :mod:`.monitor`: the accuracy monitor's rules (node and offline replay);
- :mod:`.stamp_order`: the monitor's inputs put back in stamp order before it takes them.
"""

from positioning_cell.accuracy.decisions import (
    Decision,
    DecisionRule,
    decision,
    decisions,
    norm_expanded_uncertainty,
)
from positioning_cell.accuracy.iso230_2 import AxisFigures, iso230_2
from positioning_cell.accuracy.iso9283 import (
    DistanceFigures,
    MultiDirectionalFigures,
    PoseFigures,
    approach_groups,
    distance_figures,
    iso9283,
    multidirectional_figures,
    orientation_angles,
    wrap_angle,
)
from positioning_cell.accuracy.monitor import (
    Fed,
    Ignored,
    Measured,
    Monitor,
    MonitorSettings,
    MoveEnds,
    NewSegment,
    PoseBatch,
    PoseMessages,
    TrackerErrorSettings,
    move_ended,
)
from positioning_cell.accuracy.settle import (
    AccuracyAccumulator,
    AccuracyResult,
    CheckedSamples,
    Ends,
    PoseKeys,
    SampleBatch,
    SampleUpdate,
    SegmentStart,
    SettleSettings,
    Targets,
    Visit,
    analyse,
    check_samples,
    figures_by_pose,
    measurement_error,
    settled_visits,
    stamp_seconds,
)
from positioning_cell.accuracy.tracker_errors import (
    ErrorStatistics,
    ErrorSums,
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
    decision_counts,
    judge,
    judge_poses,
    judge_visit,
    judge_visits,
)
from positioning_cell.core.poses import EULER_SEQUENCE

__all__ = [
    'EULER_SEQUENCE',
    'ORIENTATION_TOLERANCE',
    'POSITION_TOLERANCE',
    'AccuracyAccumulator',
    'AccuracyResult',
    'AxisFigures',
    'CheckedSamples',
    'Decision',
    'DecisionRule',
    'DistanceFigures',
    'Ends',
    'ErrorStatistics',
    'ErrorSums',
    'Fed',
    'Ignored',
    'Measured',
    'Monitor',
    'MonitorSettings',
    'MoveEnds',
    'MultiDirectionalFigures',
    'NewSegment',
    'PoseBatch',
    'PoseFigures',
    'PoseKeys',
    'PoseMessages',
    'SampleBatch',
    'SampleUpdate',
    'SegmentStart',
    'SettleSettings',
    'Targets',
    'Tolerances',
    'TrackerErrorAccumulator',
    'TrackerErrorSettings',
    'Verdict',
    'Visit',
    'analyse',
    'approach_groups',
    'check_samples',
    'decision',
    'decision_counts',
    'decisions',
    'distance_figures',
    'error_statistics',
    'figures_by_pose',
    'iso230_2',
    'iso9283',
    'judge',
    'judge_poses',
    'judge_visit',
    'judge_visits',
    'measurement_error',
    'move_ended',
    'multidirectional_figures',
    'norm_expanded_uncertainty',
    'orientation_angles',
    'pair_by_stamp',
    'settled_visits',
    'stamp_seconds',
    'tracker_errors',
    'wrap_angle',
]
