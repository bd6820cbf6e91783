"""``calibrate_panel``: calibrate the running coordinated cell from its panel's targets.

On the coordinated cell of ROS_DOMAIN_ID (the cell coordinator, its node sets, and the cell's
tracker reading the panel on /panel/metrology/pose): the program of
:mod:`positioning_cell.procedures.panel_calibration` (the panel home, then ``--poses`` poses
within ``--reach`` and ``--turn`` of it, then home again, at ``--speed-scale`` of the
positioners' speeds; ``--readings`` readings of the panel averaged at each), a line per pose;
then each positioner's base in the cell frame and its ball's socket in the panel identified
(:mod:`positioning_cell.coordinated.cell_calibration`), a line per positioner (its base and
socket, its residual and variance factor, and whether its model holds). The positioners'
nominal machine and the default cell file are the coordinator's (its section of ``--config``,
default config/cell.yaml). Writes the cell file ``--cell`` (default: the coordinator's
``cell_file``) with the identified bases and sockets to ``OUT/cell.yaml``; ``--load`` then
sets the coordinator's ``cell_file`` to it (its next panel move on). Ctrl-C / SIGTERM stops
every positioner (/cell_coordinator/stop) and writes nothing.

Exit status (:mod:`positioning_cell.tools.exits`): 0 written (and loaded, with ``--load``);
1 the data did not identify the cell, or a positioner's model falls short of it (nothing
written); 2 a cell file or an argument that cannot be used; 3 the coordinator refused the new
file (which stays written), or a panel move; 4 a panel move did not settle; 5 the coordinator
or the panel's tracker did not answer; 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from positioning_cell.tools.exits import Exit, exit_table, procedure_exit

if TYPE_CHECKING:
    from positioning_cell.coordinated.cell_file import CellFile
    from positioning_cell.core.mechanism import Mechanism
    from positioning_cell.procedures.panel_calibration import PanelCalibrationSettings
    from positioning_cell.ros.client import CellClient

#: The file written into ``--out``.
CELL_FILE_NAME = 'cell.yaml'


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(prog='calibrate_panel',
                                     description=__doc__.split('\n\n')[0],
                                     epilog='exit status:\n' + exit_table(),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--cell', type=Path, help="the cell file the coordinator runs "
                        "(default: --config's cell_coordinator.cell_file)")
    parser.add_argument('--config', type=Path, help='parameter file of the cell (default: the '
                        "shipped config/cell.yaml): the coordinator's machine and cell file")
    parser.add_argument('--out', type=Path, default=Path('cell_calibration'),
                        help=f'folder for {CELL_FILE_NAME} (default ./cell_calibration)')
    parser.add_argument('--poses', type=int, help='panel poses measured (default 12)')
    parser.add_argument('--reach', type=float, help="the panel's move from home per axis, "
                        'at most, m (default 0.006)')
    parser.add_argument('--turn', type=float, help="the panel's turn about each axis, at "
                        'most, rad (default 0.006)')
    parser.add_argument('--readings', type=int, help='readings averaged per pose (default 10)')
    parser.add_argument('--speed-scale', type=float, help="the panel's moves, as a share of "
                        "the positioners' speeds (default 0.25)")
    parser.add_argument('--load', action='store_true',
                        help="set the coordinator's cell_file to the new file afterwards")
    parser.add_argument('--timeout', type=float, default=120.0,
                        help='longest wait for a panel move or an answer, s (default 120)')
    args = parser.parse_args(argv)
    return run(args)


def say(text: str) -> None:
    """A progress line, at once."""
    print(text, flush=True)


def run(args: argparse.Namespace) -> int:
    """The work of the parsed command line ``args``; the exit code."""
    # numpy, scipy and the ROS adapter load now, not for --help or a usage error
    from positioning_cell import names
    from positioning_cell.config import config_path
    from positioning_cell.coordinated.settings import CellCoordinatorSettings, cell_of
    from positioning_cell.errors import PositioningError
    from positioning_cell.parameters import parse
    from positioning_cell.procedures.panel_calibration import PanelCalibrationSettings
    from positioning_cell.ros.client import CellClient
    from positioning_cell.tools.interruption import Interrupted, interruptible

    chosen = {k: getattr(args, k) for k in ('poses', 'reach', 'turn', 'readings',
                                            'speed_scale') if getattr(args, k) is not None}
    try:
        coordinator = CellCoordinatorSettings.from_file(args.config or config_path('cell.yaml'))
        cell = cell_of(str(args.cell)) if args.cell else coordinator.cell()
        settings = parse(PanelCalibrationSettings, chosen)
    except PositioningError as err:
        say(f'calibrate_panel: error: {err}')
        return Exit.USAGE
    with interruptible() as signals:
        client = CellClient(name='calibrate_panel', signals=False)
        try:
            return _calibrate(client, cell, coordinator.mechanism, settings, args)
        except Interrupted as err:
            with signals.ignored(), contextlib.suppress(TimeoutError):  # stopping goes on
                client.trigger(names.COORDINATED_STOP, args.timeout)
            say(f'calibrate_panel: interrupted ({err}): every positioner stopped, nothing '
                'written')
            return Exit.INTERRUPTED
        except TimeoutError as err:
            say(f'calibrate_panel: error: {err}')
            return Exit.NOT_THERE
        finally:
            client.close()


def _calibrate(client: CellClient, cell: CellFile, mech: Mechanism,
               settings: PanelCalibrationSettings, args: argparse.Namespace) -> Exit:
    """The program, the identification, the file written and (``--load``) loaded."""
    import yaml

    from positioning_cell import names
    from positioning_cell.errors import PositioningError
    from positioning_cell.procedures import panel_calibration as procedure
    from positioning_cell.procedures.port import ProcedureError
    from positioning_cell.ros.panel_port import RosPanelPort

    with RosPanelPort(client, timeout=args.timeout, move_timeout=args.timeout) as port:
        port.ready()
        try:
            done = procedure.run(port, cell, mech, settings, say)
        except ProcedureError as err:
            say(f'calibrate_panel: a panel move did not settle, nothing written: {err}')
            return procedure_exit(err.code)
        except PositioningError as err:  # the poses cannot identify the cell
            say(f'calibrate_panel: not identified, nothing written: {err}')
            return Exit.NOT_ACHIEVED
    for line in procedure.summary(done.calibration):
        say(line)
    if not done.calibration.adequate:
        say('calibrate_panel: a positioner has more error than its model explains, nothing '
            'written')
        return Exit.NOT_ACHIEVED
    args.out.mkdir(parents=True, exist_ok=True)
    path = (args.out / CELL_FILE_NAME).resolve()
    path.write_text(yaml.safe_dump(done.calibration.applied(cell).as_yaml(), sort_keys=False))
    say(f'written: {path}')
    if not args.load:
        return Exit.OK
    result = client.set_parameter(names.NODE_COORDINATOR, 'cell_file', str(path))
    if not result.successful:
        say(f'calibrate_panel: the coordinator refused the new file: {result.reason}')
        return Exit.REFUSED
    say(f'loaded: /{names.NODE_COORDINATOR} cell_file = {path}')
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
