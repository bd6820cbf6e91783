"""``axis_test``: the axis test on the running cell of ``ROS_DOMAIN_ID`` (ISO 230-2:2014 per
actuator; the procedure: :mod:`positioning_cell.procedures.axis_test`; ``run_cell
--axis-test`` runs it after the calibration):

    python -m positioning_cell.tools.axis_test [--program F] [--config F] [--out DIR]

A line per measured stop, a marker per stop on ``/cell/axis_test`` (recorded when a recorder
runs), then the ISO 230-2 table of each axis (``--out``: also ``axis_test.md`` and
``axis_test.json``). Ctrl-C / SIGTERM stops the drives and puts the mode back.

Exit status (:mod:`positioning_cell.tools.exits`): 0 done; 2 the program or the config cannot
be used; 3 the positioner refused mode none or a step (refused_*); 4 a step was aborted, the
test could not be completed; 5 the cell did not answer (a service, the readings); 130
interrupted.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from positioning_cell.analysis.axis_test import load_axis_test
from positioning_cell.config import config_path
from positioning_cell.errors import PositioningError
from positioning_cell.motion.settings import machine_settings
from positioning_cell.procedures.axis_test import ModeRefusedError, run_axis_test, write
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.port import RosCellPort
from positioning_cell.tools.exits import Exit, exit_table, procedure_exit
from positioning_cell.tools.interruption import Interrupted, interruptible


def say(text: str) -> None:
    """A progress line, at once."""
    print(text, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(
        prog='axis_test', formatter_class=argparse.RawDescriptionHelpFormatter,
        description='The axis test (ISO 230-2:2014 per actuator) on the running cell of '
        'ROS_DOMAIN_ID: a line per measured stop, then the ISO 230-2 tables.',
        epilog='exit status:\n' + exit_table())
    parser.add_argument('--program', type=Path, help='axis-test file (default: the shipped '
                        'config/axis_test.yaml)')
    parser.add_argument('--config', type=Path, help='parameter file of the cell (default: the '
                        'shipped config/cell.yaml): the machine, and the truth to judge by')
    parser.add_argument('--out', type=Path, help='write axis_test.md and axis_test.json here')
    parser.add_argument('--no-truth', action='store_true',
                        help='do not judge by the simulator\'s truth')
    args = parser.parse_args(argv)
    try:
        config = args.config or config_path('cell.yaml')
        settings = machine_settings(config)
        test = load_axis_test(args.program or config_path('axis_test.yaml'), settings.mechanism)
    except PositioningError as err:
        say(f'axis_test: error: {err}')
        return Exit.USAGE
    client: CellClient | None = None
    with interruptible():
        try:
            client = CellClient(name='axis_test', signals=False)
            results = run_axis_test(RosCellPort(client), test, config, say,
                                    judge=not args.no_truth).results
        except Interrupted:  # the procedure stopped the drives and put the mode back
            say('axis_test: interrupted: drives stopped')
            return Exit.INTERRUPTED
        except ProcedureError as err:
            say(f'axis_test: error: {err}')
            return procedure_exit(err.code, isinstance(err, ModeRefusedError))
        except TimeoutError as err:
            say(f'axis_test: error: {err}')
            return Exit.NOT_THERE
        except PositioningError as err:  # the calibration file the positioner names
            say(f'axis_test: error: {err}')
            return Exit.USAGE
        finally:
            if client is not None:
                client.close()
    say('\n'.join(results.summary()))
    say('\n'.join(results.markdown()))
    if args.out is not None:
        md, js = write(results, args.out)
        say(f'tables: {md}\nJSON:   {js}')
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
