"""``run_cell`` (``make run``): run the positioning cell on its embedded defaults and analyse
the run.

Starts the cell's nodes as separate processes (as ``launch/cell.launch.py`` does on a ROS
install), each in its own process group, on a private ROS_DOMAIN_ID with discovery limited to
this machine; records everything into ``runs/<UTC timestamp>/bag``; drives the program of
``config/program.yaml`` (each compensation mode set on the positioner, then its cycles of
moves through ``/positioner/move_to_pose``), printing a line per move with the monitor's
verdict; stops every process (SIGINT, SIGKILL after a grace period, also on Ctrl-C / SIGTERM);
analyses the bag (``positioning_cell.tools.analyze_bag``) into the same folder; prints the
comparison table and where the bag, report and plots are. The run itself (calibration, axis
test, program) is :mod:`positioning_cell.procedures.program_run` on the ROS port; the start of
the cell is :mod:`positioning_cell.ros.cell_start`.

With ``--axis-test [FILE]`` (default ``config/axis_test.yaml``) the driver runs the axis test
after the calibration and before the modes (ISO 230-2:2014 per actuator,
:mod:`positioning_cell.procedures.axis_test`): a line per measured stop, a marker per stop on
``/cell/axis_test`` (recorded), and at the end the ISO 230-2 table of each axis, also written to
``axis_test.md`` and ``axis_test.json`` in the run folder.

Before each move the driver publishes the step on ``/cell/program`` (std_msgs/String,
transient-local, JSON of :class:`positioning_cell.analysis.ProgramStep`), which is recorded, so
the analysis knows the mode and pose name of every move. Exit status
(:mod:`positioning_cell.tools.exits`): 0 done; 1 done, but a move failed, a mode was refused,
the axis test or the analysis was partial; 2 a bad program or config (nothing started); 5 the
cell did not come up or stopped answering; 130 interrupted (the processes are stopped and what
was recorded is analysed).

With ``--cell FILE`` (e.g. ``config/three_positioners.yaml``) it runs the coordinated cell of
that file instead: its positioners holding one panel, the cell calibrated from the panel's
targets, then the panel program of ``--panel-program`` (default ``config/panel_program.yaml``),
recorded and analysed into the panel's ISO 9283 figures
(:mod:`positioning_cell.tools.cell_run_panel`); its nodes take ``--cell-config`` (default
``config/coordinated.yaml``) after ``--config``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from positioning_cell.tools.exits import exit_table
from positioning_cell.tools.lazy import attributes_of

#: ``--axis-test`` without a file: the shipped config/axis_test.yaml.
SHIPPED_AXIS_TEST = Path('<shipped axis_test.yaml>')


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``run_cell [--program F] [--config F] [--runs DIR] [--axis-test [F]]
    [--cell F [--panel-program F]]``."""
    parser = argparse.ArgumentParser(
        prog='run_cell', formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Run the positioning cell (all nodes, recorder) through a program of poses '
        'under each compensation mode, then analyse the recording.',
        epilog='exit status:\n' + exit_table())
    parser.add_argument('--program', type=Path,
                        help='program file (default: the shipped config/program.yaml)')
    parser.add_argument('--config', type=Path,
                        help='ROS 2 parameter file of the cell (default: config/cell.yaml)')
    parser.add_argument('--runs', type=Path, default=Path('runs'),
                        help='folder for the run folders (default: ./runs)')
    parser.add_argument('--axis-test', type=Path, nargs='?', const=SHIPPED_AXIS_TEST,
                        metavar='FILE', help='after the calibration, run the axis test '
                        '(ISO 230-2 per actuator) of FILE (default: the shipped '
                        'config/axis_test.yaml)')
    parser.add_argument('--cell', type=Path, metavar='FILE', help='run the coordinated cell '
                        'of this cell file (e.g. config/three_positioners.yaml) through its '
                        'calibration and the panel program')
    parser.add_argument('--panel-program', type=Path, metavar='FILE', help='with --cell: the '
                        'panel program (default: the shipped config/panel_program.yaml)')
    parser.add_argument('--cell-config', type=Path, metavar='FILE', help='with --cell: a '
                        "parameter file after --config for the cell's nodes (default: "
                        'config/coordinated.yaml, liveness and rates for several node sets '
                        'on one machine)')
    args = parser.parse_args(argv)
    if args.cell is None and (args.panel_program is not None or args.cell_config is not None):
        parser.error('--panel-program and --cell-config need --cell')
    if args.cell is not None and (args.program is not None or args.axis_test is not None):
        parser.error('--cell runs the panel program: not with --program or --axis-test')
    # the work (numpy, rclpy, the analysis) loads now, not for --help or a usage error
    from positioning_cell.config import config_path
    from positioning_cell.tools.cell_run import run

    if args.cell is not None:
        from positioning_cell.tools import cell_run_panel

        return cell_run_panel.run(args.cell, args.panel_program, args.config, args.runs,
                                  lambda s: print(s, flush=True), args.cell_config)

    axis_file = args.axis_test
    if axis_file == SHIPPED_AXIS_TEST:
        axis_file = config_path('axis_test.yaml')
    return run(args.program, args.config, args.runs, lambda s: print(s, flush=True), axis_file)


def _work() -> ModuleType:
    from positioning_cell.tools import cell_run

    return cell_run


#: The work's names (``run``, ...) as this module's too.
__getattr__ = attributes_of(_work, __name__)

if __name__ == '__main__':
    sys.exit(main())
