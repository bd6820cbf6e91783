"""``calibrate_cell``: calibrate the running cell, or a recorded calibration run.

Live (default): the calibration procedure (:func:`positioning_cell.procedures.calibration.
calibrate`) on the cell of ``ROS_DOMAIN_ID``: the positioner is homed and set to mode
``none``; the measurement program (poses chosen by ``--criterion`` D, I or G, the latter two
for the production poses of ``--production``'s ``production:`` block, and hold-out poses;
the program's criterion, predicted pose sigma there and observability indices are said) is
driven through ``/positioner/move_to_pose``; at each pose ``--samples`` tracker readings are
taken and a marker goes out on ``/cell/calibration``; a line per pose says how far the
measured pose is from the commanded one and, every ten poses, the residual of a fit so far.
Then the machine is identified, validated on the hold-out poses, and ``OUT/calibration.yaml``
and ``OUT/calibration_report.md`` (with plots, the observability indices of the poses
measured and the predicted pose sigma at the production poses) are written; the
positioner's mode is put back.
``--load`` also sets the positioner's ``compensation.calibration_file`` to the new file.
Ctrl-C / SIGTERM stops the move (``/positioner/stop``), puts the mode back and writes nothing.

``--from-bag BAG``: the same identification from a recording of such a run (the markers, the
encoder readings and the tracker poses: :mod:`positioning_cell.calibration.bag`), the same
result from the same data.

Exit status (:mod:`positioning_cell.tools.exits`): 0 written (and loaded, with ``--load``);
1 the data did not identify the machine (nothing written); 2 the configuration or the bag
cannot be used; 3 the positioner refused homing, mode ``none`` or (``--load``) the new file
(which stays written); 4 the homing aborted; 5 the cell did not answer or the tracker gave no
reading in time; 130 interrupted (drives stopped, mode put back, nothing written).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from positioning_cell.calibration.program_settings import (
    APPROACH_RULES,
    CRITERIA,
    ProgramSettings,
)
from positioning_cell.tools.exits import exit_table
from positioning_cell.tools.lazy import attributes_of


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    defaults = ProgramSettings()
    parser = argparse.ArgumentParser(prog='calibrate_cell', description=__doc__.split('\n\n')[0],
                                     epilog='exit status:\n' + exit_table(),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=Path, default=Path('calibration'),
                        help='folder for calibration.yaml and the report (default ./calibration)')
    parser.add_argument('--from-bag', type=Path, help='identify from a recorded calibration run')
    parser.add_argument('--run', help='with --from-bag: which run (its start, as printed; '
                        'default: the last in the bag)')
    parser.add_argument('--config', type=Path, help='parameter file of the cell (default: the '
                        'shipped config/cell.yaml): the nominal machine and its payload')
    parser.add_argument('--poses', type=int, default=defaults.poses)
    parser.add_argument('--hold-out', type=int, default=defaults.hold_out)
    parser.add_argument('--samples', type=int, default=10,
                        help='tracker readings averaged per pose')
    parser.add_argument('--seed', type=int, default=defaults.seed, help='candidate draw')
    parser.add_argument('--criterion', choices=CRITERIA, default=defaults.criterion,
                        help='design criterion of the program: D (log det of the information), '
                        'I (mean predicted pose variance at the production poses), G (worst '
                        f'there); default {defaults.criterion}')
    parser.add_argument('--production', type=Path, help='program file whose production: block '
                        'says where the cell is used (default: the shipped config/program.yaml)')
    parser.add_argument('--approach', type=float, default=defaults.approach,
                        help='approach each pose from this far from it along base z, m (0: '
                        'directly)')
    parser.add_argument('--approach-rule', choices=APPROACH_RULES,
                        default=defaults.approach_rule,
                        help='below: every pose from below; alternate: from below and from '
                        'above in turn, so each axis is seen from both sides (its reversal '
                        f'identifiable); default {defaults.approach_rule}')
    parser.add_argument('--load', action='store_true',
                        help='set the positioner\'s compensation.calibration_file afterwards')
    args = parser.parse_args(argv)
    from positioning_cell.tools.cell_calibration import run  # the work: scipy, the bag reader

    return run(args, defaults)


def _work() -> ModuleType:
    from positioning_cell.tools import cell_calibration

    return cell_calibration


#: The work's names (``exit_code``, ...) as this module's too.
__getattr__ = attributes_of(_work, __name__)

if __name__ == '__main__':
    sys.exit(main())
