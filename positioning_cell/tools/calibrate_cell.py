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
import contextlib
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import observability as obs
from positioning_cell.calibration import program as prog
from positioning_cell.calibration.bag import read_bag
from positioning_cell.calibration.identified import identify_and_write
from positioning_cell.config import config_path
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import PositionerSettings, machine_settings
from positioning_cell.polling import wait_until
from positioning_cell.procedures.calibration import Outcome, Status, calibrate
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.tools.exits import Exit, exit_table
from positioning_cell.tools.interruption import Interrupted, interruptible

#: The exit code of each way a calibration ends.
EXITS = {Status.WRITTEN: Exit.OK, Status.NOT_IDENTIFIED: Exit.NOT_ACHIEVED,
         Status.REFUSED: Exit.REFUSED, Status.ABORTED: Exit.ABORTED,
         Status.NOT_THERE: Exit.NOT_THERE}
#: After an interrupt, the longest wait for the interrupted call's answer, s.
ANSWER_WAIT = 10.0


def exit_code(outcome: Outcome) -> Exit:
    """The exit code of a calibration's outcome (a written file the positioner refused to
    load: :attr:`Exit.REFUSED`)."""
    if outcome.status is Status.WRITTEN and outcome.loaded is False:
        return Exit.REFUSED
    return EXITS[outcome.status]


def say(text: str) -> None:
    """A progress line, at once."""
    print(text, flush=True)


def _from_bag(args: argparse.Namespace, machine: PositionerSettings) -> Exit:
    try:
        collected = read_bag(args.from_bag, args.run, say)
    except PositioningError as err:
        say(f'calibrate_cell: error: {err}')
        return Exit.USAGE
    try:
        identify_and_write(machine, collected, args.out, {'from_bag': str(args.from_bag)}, say)
    except idf.IdentificationError as err:
        say(f'calibrate_cell: not identified, nothing written: {err}')
        return Exit.NOT_ACHIEVED
    return Exit.OK


def _live(args: argparse.Namespace, machine: PositionerSettings,
          settings: prog.ProgramSettings) -> Exit:
    # The ROS adapter only here: --from-bag and --help run without rclpy.
    from positioning_cell.ros.client import CellClient
    from positioning_cell.ros.port import RosCellPort

    with interruptible() as signals:
        client: CellClient | None = None
        port: RosCellPort | None = None
        try:
            client = CellClient(name='calibrate_cell', signals=False)
            port = RosCellPort(client)
            outcome = calibrate(port, machine, settings, args.samples, args.out, say,
                                load=args.load)
            return exit_code(outcome)
        except Interrupted as err:
            with signals.ignored():  # stopping is not interrupted
                if port is not None and client is not None:
                    port.stop()
                    with contextlib.suppress(TimeoutError):
                        wait_until(client.answered, ANSWER_WAIT, 'the interrupted call')
            say(f'calibrate_cell: interrupted ({err}): drives stopped, nothing written')
            return Exit.INTERRUPTED
        except (TimeoutError, ProcedureError) as err:
            say(f'calibrate_cell: error: {err}')
            return Exit.NOT_THERE
        finally:
            if client is not None:
                client.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    defaults = prog.ProgramSettings()
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
    parser.add_argument('--criterion', choices=obs.CRITERIA, default=defaults.criterion,
                        help='design criterion of the program: D (log det of the information), '
                        'I (mean predicted pose variance at the production poses), G (worst '
                        f'there); default {defaults.criterion}')
    parser.add_argument('--production', type=Path, help='program file whose production: block '
                        'says where the cell is used (default: the shipped config/program.yaml)')
    parser.add_argument('--approach', type=float, default=defaults.approach,
                        help='approach each pose from this far from it along base z, m (0: '
                        'directly)')
    parser.add_argument('--approach-rule', choices=prog.APPROACH_RULES,
                        default=defaults.approach_rule,
                        help='below: every pose from below; alternate: from below and from '
                        'above in turn, so each axis is seen from both sides (its reversal '
                        f'identifiable); default {defaults.approach_rule}')
    parser.add_argument('--load', action='store_true',
                        help='set the positioner\'s compensation.calibration_file afterwards')
    args = parser.parse_args(argv)
    try:
        machine = machine_settings(args.config or config_path('cell.yaml'))
        settings = replace(defaults, poses=args.poses, hold_out=args.hold_out, seed=args.seed,
                           approach=args.approach, approach_rule=args.approach_rule,
                           criterion=args.criterion,
                           production=str(args.production or ''))
    except PositioningError as err:
        say(f'calibrate_cell: error: {err}')
        return Exit.USAGE
    if args.from_bag is not None:
        return _from_bag(args, machine)
    return _live(args, machine, settings)


if __name__ == '__main__':
    sys.exit(main())
