"""The ``calibration.program`` settings (:mod:`positioning_cell.calibration.program` chooses
the program by them): a module of its own, light, so that ``calibrate_cell --help`` shows
their defaults without loading the program's mathematics."""

from __future__ import annotations

from dataclasses import dataclass

from positioning_cell.parameters import check_fields, setting

#: The design criteria a program can be chosen by
#: (:mod:`positioning_cell.calibration.observability`).
CRITERIA = ('D', 'I', 'G')
#: Where a program's poses are approached from
#: (:func:`positioning_cell.calibration.program.approach_poses`).
APPROACH_RULES = ('below', 'alternate')


@dataclass(frozen=True)
class ProgramSettings:
    """The ``calibration.program`` block: how many poses, where candidates come from."""

    poses: int = setting(60, 'calibration poses measured', low=8, high=1000)
    hold_out: int = setting(20, 'validation poses, never used in the fit', low=0, high=1000)
    candidates: int = setting(3000, 'candidate poses drawn to choose from', low=10,
                              high=100000)
    position_span: tuple[float, float, float] = setting(
        (0.015, 0.015, 0.012), 'half-widths of the candidate box around home', 'm')
    rotation_span: float = setting(0.12, 'largest rotation-vector component of a candidate',
                                   'rad', low=0.0, high=1.0)
    seed: int = setting(0, 'seed of the candidate draw', low=0, high=2**31 - 1)
    approach: float = setting(0.0005, 'each pose is approached from this far from it along '
                              'base z, as approach_rule says (0: directly)', 'm', low=0.0,
                              high=0.005)
    approach_rule: str = setting('alternate', 'where poses are approached from: below (every '
                                 'pose from below, the same way every time) or alternate '
                                 '(successive poses from below and from above, so each axis '
                                 'is seen from both sides and a reversal error is '
                                 'identifiable)', choices=APPROACH_RULES)
    criterion: str = setting('D', 'design criterion of the program: D (log det of the '
                             'information), I (mean predicted pose variance at the production '
                             'poses), G (worst predicted pose variance there)',
                             choices=CRITERIA)
    production: str = setting('', 'program file whose production: block says where the cell '
                              'is used (empty: the shipped config/program.yaml)')

    def __post_init__(self) -> None:
        check_fields(self)
