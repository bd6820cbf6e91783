"""The work of ``calibrate_cell`` (:mod:`positioning_cell.tools.calibrate_cell`: the command
line and the exit status): live, or from a recorded run; imported once the command line is
parsed."""
from __future__ import annotations

import argparse
import contextlib
from dataclasses import replace

from positioning_cell.calibration import identify as idf
from positioning_cell.calibration.bag import read_bag
from positioning_cell.calibration.identified import identify_and_write
from positioning_cell.calibration.program_settings import ProgramSettings
from positioning_cell.config import config_path
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import PositionerSettings, machine_settings
from positioning_cell.polling import wait_until
from positioning_cell.procedures.calibration import Outcome, Status, calibrate
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.tools.exits import Exit
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
          settings: ProgramSettings) -> Exit:
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


def run(args: argparse.Namespace, defaults: ProgramSettings) -> int:
    """Run ``calibrate_cell`` with parsed command-line ``args`` (the program's settings:
    ``defaults`` and the arguments); its exit code."""
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
