"""``predict_accuracy``: predicted accuracy of the 3-UPS positioner for a tolerance spec.

Reads the mechanism from ``config/cell.yaml`` (or ``--config``) and a tolerance spec
(``config/tolerances.yaml`` or ``--spec``); prints the sensitivity table at a pose (default
home), the worst case / RSS / Monte Carlo comparison and the yield; writes workspace maps, the
angle-distribution fits, the seed 003 stacked-stage curves and ``summary.txt`` to ``--out``.
:func:`predict` does the work (tests call it); :func:`main` parses the command line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from positioning_cell.tools.exits import exit_table
from positioning_cell.tools.lazy import attributes_of


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``predict_accuracy [--config F] [--spec F] [--out D] ...``; exit
    ``Exit.OK`` on success, ``Exit.USAGE`` with a message on stderr for a bad config, spec or
    pose (:mod:`positioning_cell.tools.exits`)."""
    parser = argparse.ArgumentParser(
        prog='predict_accuracy', description='Predicted accuracy of the 3-UPS positioner '
        '(sensitivity, worst case, RSS, Monte Carlo yield, maps; seeds 003 and 004).',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--config', type=Path, help='ROS 2 parameter file with the mechanism '
                        '(default: the shipped config/cell.yaml)')
    parser.add_argument('--spec', type=Path, help='tolerance spec YAML (default: the shipped '
                        'config/tolerances.yaml)')
    parser.add_argument('--out', type=Path, default=Path('accuracy_prediction'),
                        help='output folder for the figures and summary.txt')
    parser.add_argument('--position', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                        help='platform position, m, base frame (default: home)')
    parser.add_argument('--rotvec', type=float, nargs=3, default=(0.0, 0.0, 0.0),
                        metavar=('RX', 'RY', 'RZ'), help='platform rotation vector, rad')
    parser.add_argument('--samples', type=int, default=1_000_000, help='Monte Carlo samples')
    parser.add_argument('--seed', type=int, default=0, help='random seed')
    parser.add_argument('--grid', type=int, default=21, help='map grid size per axis (0: none)')
    parser.add_argument('--half-width', type=float, default=0.05,
                        help='map half width, m (default 0.05)')
    parser.add_argument('--stacked-runs', type=int, default=10_000,
                        help='runs of the seed 003 stacked-stage study (0: none)')
    parser.add_argument('--global-runs', type=int, default=1_000,
                        help='runs of the exhaustive global strategy (costly: 6^7 per run)')
    parser.add_argument('--calibration', type=Path,
                        help='calibration.yaml of the machine (calibrate_cell): also print the '
                        'calibrated machine\'s uncertainty at the pose')
    args = parser.parse_args(argv)
    from positioning_cell.tools.accuracy_prediction import run  # the work: numpy, scipy, numba

    return run(args)


def _work() -> ModuleType:
    from positioning_cell.tools import accuracy_prediction

    return accuracy_prediction


#: The work's names (``predict``, ``shipped_config``, ...) as this module's too.
__getattr__ = attributes_of(_work, __name__)

if __name__ == '__main__':
    sys.exit(main())
