"""Offline analysis of recorded cell runs (pure library, no rclpy): the run program
(:mod:`.program`), a bag read in recorded order (:mod:`.reading`), replayed through the
accuracy monitor's rules (:mod:`positioning_cell.accuracy.monitor`, :mod:`.replay`),
summarised per compensation mode and commanded pose (:mod:`.summary`), written as a Markdown
report and a JSON summary (:mod:`.report`) and plotted (:mod:`.plots`)."""

from positioning_cell.analysis.program import Program, ProgramStep, load_program
from positioning_cell.analysis.reading import BagContents, read_bag
from positioning_cell.analysis.replay import (
    OPTIONAL_TOPICS,
    REQUIRED_TOPICS,
    LabelledVisit,
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
    'REQUIRED_TOPICS',
    'BagContents',
    'Extremes',
    'LabelledVisit',
    'ModeSummary',
    'PoseSummary',
    'Program',
    'ProgramStep',
    'Replay',
    'RunAnalysis',
    'Segment',
    'analyse_bag',
    'load_program',
    'read_bag',
    'replay',
    'summarise',
]
