"""The ``calibrator`` node's settings: the live calibration one Calibrate goal runs
(``calibrate_cell``'s procedure: the program, tracker readings per pose, where the file goes,
whether the positioner loads it, and the parameter file of the nominal machine)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.config import config_path
from positioning_cell.parameters import check_fields, group, setting


@dataclass(frozen=True)
class CalibratorSettings:
    """Every parameter of the ``calibrator`` node (a goal's non-zero ``poses``, ``hold_out``
    and ``samples`` replace the configured ones: :meth:`for_goal`)."""

    out_dir: str = setting('calibration', 'folder of calibration.yaml and its report '
                           '(relative: to the working directory of the node)')
    config: str = setting('', 'parameter file of the nominal machine (its positioner section: '
                          'mechanism, payload, structure, motion); empty: the shipped '
                          'config/cell.yaml')
    program: ProgramSettings = group(ProgramSettings, 'the measurement program')
    samples: int = setting(10, 'tracker readings averaged per pose', low=1, high=1000)
    timeout: float = setting(10.0, 'longest wait for the tracker readings of one pose', 's',
                             low=0.1, high=600.0)
    load: bool = setting(True, "set the positioner's compensation.calibration_file to the new "
                         'file afterwards')

    def __post_init__(self) -> None:
        check_fields(self)

    def for_goal(self, poses: int, hold_out: int, samples: int) -> CalibratorSettings:
        """These settings with a goal's numbers, 0 meaning the configured one (ConfigError:
        one out of its range)."""
        program = replace(self.program, poses=poses or self.program.poses,
                          hold_out=hold_out or self.program.hold_out)
        return replace(self, program=program, samples=samples or self.samples)

    def machine_file(self) -> Path:
        """The parameter file of the nominal machine."""
        return Path(self.config) if self.config else config_path('cell.yaml')
