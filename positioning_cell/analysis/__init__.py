"""Offline analysis of recorded cell runs (pure library, no rclpy): a bag read in recorded
order (:mod:`.reading`), replayed through the accuracy monitor's rules (:mod:`.monitor`,
:mod:`.replay`), summarised per compensation mode and commanded pose (:mod:`.summary`), written
as a Markdown report and a JSON summary (:mod:`.report`) and plotted (:mod:`.plots`)."""

from positioning_cell.analysis.monitor import Ignored, MonitorReplay, MonitorSettings
from positioning_cell.analysis.reading import BagContents, read_bag
from positioning_cell.analysis.replay import (
    OPTIONAL_TOPICS,
    PROGRAM_TOPIC,
    REQUIRED_TOPICS,
    LabelledVisit,
    ProgramStep,
    Replay,
    Segment,
    replay,
)
from positioning_cell.analysis.summary import (
    Extremes,
    ModeSummary,
    PoseSummary,
    RunAnalysis,
    analyse_bag,
    summarise,
)

__all__ = [
    'OPTIONAL_TOPICS',
    'PROGRAM_TOPIC',
    'REQUIRED_TOPICS',
    'BagContents',
    'Extremes',
    'Ignored',
    'LabelledVisit',
    'ModeSummary',
    'MonitorReplay',
    'MonitorSettings',
    'PoseSummary',
    'ProgramStep',
    'Replay',
    'RunAnalysis',
    'Segment',
    'analyse_bag',
    'read_bag',
    'replay',
    'summarise',
]
