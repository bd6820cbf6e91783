"""Offline analysis of recorded cell runs (pure library, no rclpy): the run program
(:mod:`.program`), a bag read in recorded order in batches of arrays (:mod:`.reading`),
replayed through the accuracy monitor's rules (:mod:`positioning_cell.accuracy.monitor`,
:mod:`.replay`) with the error over time kept as a bounded trace (:mod:`.trace`) and the run's
context (calibration, tracker registrations: :mod:`.context`), summarised per compensation
mode and commanded pose (:mod:`.summary`), written as a Markdown report and a JSON summary
(:mod:`.report`), as an acceptance record of every ISO 9283 characteristic with its U and
decision (:mod:`.acceptance`) and plotted (:mod:`.plots`)."""

from positioning_cell.analysis.program import Program, ProgramStep, load_program
from positioning_cell.analysis.reading import Recording, message_batches, with_recording
from positioning_cell.analysis.replay import (
    OPTIONAL_TOPICS,
    REQUIRED_TOPICS,
    LabelledVisit,
    MessageBatch,
    Replay,
    Replayer,
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
    'Extremes',
    'LabelledVisit',
    'MessageBatch',
    'ModeSummary',
    'PoseSummary',
    'Program',
    'ProgramStep',
    'Recording',
    'Replay',
    'Replayer',
    'RunAnalysis',
    'Segment',
    'analyse_bag',
    'load_program',
    'message_batches',
    'replay',
    'summarise',
    'with_recording',
]
