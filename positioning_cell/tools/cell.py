"""``cell``: the operator's command-line client of the running positioning cell.

Poses are six human numbers, Tx Ty Tz in mm and Rx Ry Rz in degrees with R = Rz·Ry·Rx; on the
wire everything is SI. Text for people by default; ``--json`` prints one JSON object on stdout
instead (:mod:`positioning_cell.tools.cell_format`: ``command``, ``exit_code``, ``exit_name``,
``error`` and every field of the answer, NaN and infinities as null)::

    cell up [--live-view] [--calibrator]         the whole cell in the foreground (logs and
            [--no-record] [--params-file YAML]   bag in runs/<UTC time>/); Ctrl-C stops it
    cell status                                  state, drives, user and machine positions
    cell move TX TY TZ RX RY RZ                  absolute, the object in the user CS
         [--relative-user | --relative-object | --frame base|machine|user]
         [--tolerance MM] [--speed-scale S]      (action /positioner/move, with progress)
    cell check TX TY TZ RX RY RZ [same options]  the checks of that move, nothing moves
    cell frames get
    cell frames set [--user 6] [--object 6]      one left out stays as it is
    cell frames define user|object NAME 6 [--use]   store a named system (and use it)
    cell frames use [--user NAME] [--object NAME]   switch the active named systems
    cell watch [--frame user|base] [--rate HZ]   the live watch window; q or Ctrl-C quits
    cell home                                    reference if needed, then home (action)
    cell stop                                    controlled stop of whatever runs
    cell jog AXIS DELTA                          leg1_length ... (mm), leg1_theta ... (deg)
    cell speed [--linear MM_S] [--angular DEG_S] [--linear-acceleration MM_S2]
               [--angular-acceleration DEG_S2]   no option: query
    cell limits get
    cell limits set [--machine-lower 6] [--machine-upper 6] [--user-lower 6] [--user-upper 6]
    cell limits reset                            the factory's: machine box = factory box,
                                                 no user box

Common options on every command, before or after it: ``--json``, ``--timeout S`` (default
300 s for move and home, 20 s otherwise; a goal still running then is cancelled), ``--domain
ID`` (default: ROS_DOMAIN_ID of the environment). As the cell's own processes, the client
keeps to the loopback (``loopback_only``) unless the environment names its own Fast DDS
profile.

Ctrl-C (or SIGTERM) during a move or a homing cancels the goal (a controlled stop) and waits
for its result, ``aborted_stop`` (exit 4); a second Ctrl-C stops waiting (exit 130). The
progress bar is one line on stderr, drawn only when stderr is a terminal.

``status`` converts the platform poses of /positioner/target (latched) and /positioner/pose
(the estimate) with the coordinate systems (GetCoordinateSystems) and the positioner's
``mechanism.*`` parameters (the machine CS: zero at the home pose).

Exit codes: the one table of every command line (:mod:`positioning_cell.tools.exits`;
``cell --help`` prints it). What each means for ``cell``:

====  =================  ======================================================================
code  name               when
====  =================  ======================================================================
0     success            done: settled within the tolerance, a valid check, a query answered,
                         a setting taken
1     out_of_tolerance   settled, but not within the tolerance
2     usage              bad command line (argparse), nothing sent
3     refused            refused, nothing moved: any refused_* code, a goal rejected, an
                         invalid check, a setting or jog refused
4     aborted            aborted, the drives were stopped: any aborted_* code, a cancel by
                         Ctrl-C or by --timeout (aborted_stop), or no outcome given
5     not_there          the cell is not there: a service, action server, status or answer
                         did not come within --timeout
130   interrupted        Ctrl-C outside a goal, or a second Ctrl-C while a cancelled goal
                         winds down (its result not awaited)
====  =================  ======================================================================

The command line is :mod:`~positioning_cell.tools.cell_parser` (standard library only:
``--help`` and a usage error answer before numpy, rclpy or rich load); the commands,
:mod:`~positioning_cell.tools.cell_commands`, are imported once it is parsed. The ROS half
(services, actions, messages) is :mod:`positioning_cell.ros.operator_client`, imported when a
command runs: :mod:`~positioning_cell.tools.cell_format` loads without ROS.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from types import ModuleType

from positioning_cell.tools.cell_parser import build_parser
from positioning_cell.tools.lazy import attributes_of


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring). The commands (and numpy, rclpy, rich with them) are
    imported only once the line is parsed: ``--help`` and a usage error answer at once."""
    args = build_parser((__doc__ or '').split('\n\n')[0].replace('``', '')).parse_args(argv)
    if args.command == 'up':  # starts the cell's processes, no client of it
        from positioning_cell.tools.cell_up import up

        return up(args)
    # The client's node first: its participant discovers the cell while the commands import.
    from positioning_cell.ros.early import start_node

    node = start_node(args.domain)
    from positioning_cell.tools.cell_commands import run

    return run(args, node)


def _commands() -> ModuleType:
    from positioning_cell.tools import cell_commands

    return cell_commands


#: The commands' names (``Report``, ``Output``, ``COMMANDS``, ...) as this module's too.
__getattr__ = attributes_of(_commands, __name__)

if __name__ == '__main__':
    sys.exit(main())
