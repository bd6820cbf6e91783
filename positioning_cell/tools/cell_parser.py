"""The command line of ``cell`` (:mod:`positioning_cell.tools.cell`): its parser, options and
defaults. Standard library and :mod:`positioning_cell.names` only: ``cell --help`` and a bad
command line answer before numpy, rclpy or rich load (issue 24)."""

from __future__ import annotations

import argparse
import math
from typing import Any

from positioning_cell.names import ABSOLUTE_FRAMES, JOINT_NAMES, USER_FRAME, WATCH_FRAMES
from positioning_cell.tools.exits import exit_table

#: The word for an unlimited bound on the command line and in text.
NO_LIMIT = 'none'

# -- the command line ----------------------------------------------------------------------------
#: MoveCommand's modes (the .msg's constants; the test checks them against the message).
MODE_ABSOLUTE = 0
MODE_RELATIVE_USER = 1
MODE_RELATIVE_OBJECT = 2
MODE_NAMES = {MODE_ABSOLUTE: 'absolute', MODE_RELATIVE_USER: 'relative_user',
              MODE_RELATIVE_OBJECT: 'relative_object'}

#: The subcommands that are clients of a running cell (``command`` of the parsed arguments
#: and of the JSON document; tools.cell_commands runs them).
CLIENT_COMMANDS = ('status', 'move', 'check', 'frames get', 'frames set', 'frames define',
                   'frames use', 'home', 'stop', 'jog', 'speed', 'limits get', 'limits set',
                   'limits reset', 'watch')
#: Every subcommand: the clients, and ``up``, which starts the cell (tools.cell_up).
COMMANDS = (*CLIENT_COMMANDS, 'up')
#: Default --timeout (s): moves and homing may take minutes; anything else is a quick answer.
GOAL_TIMEOUT = 300.0
QUICK_TIMEOUT = 20.0
DEFAULT_TIMEOUTS = {'move': GOAL_TIMEOUT, 'home': GOAL_TIMEOUT}


def default_timeout(command: str) -> float:
    """The --timeout of ``command`` when none is given (s)."""
    return DEFAULT_TIMEOUTS.get(command, QUICK_TIMEOUT)


def _finite_number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'not a finite number: {text!r}')
    return value


def _non_negative(text: str) -> float:
    value = _finite_number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f'must not be negative: {text!r}')
    return value


def _positive(text: str) -> float:
    value = _finite_number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f'must be positive: {text!r}')
    return value


def _scale(text: str) -> float:
    value = _finite_number(text)
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f'must be in (0, 1]: {text!r}')
    return value


def _domain(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f'a ROS domain id is 0..232: {text!r}')
    return value


def _bound(text: str) -> float:
    """A limit bound: a number, ``inf``, or ``none`` (no limit: NaN here, given its sign by
    the side it bounds in
    :meth:`positioning_cell.tools.cell_format.LimitBoxes.merged`)."""
    if text.strip().lower() == NO_LIMIT:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number or {NO_LIMIT!r}: {text!r}') from None
    if math.isnan(value):
        raise argparse.ArgumentTypeError(f'not a number: {text!r} (no limit: {NO_LIMIT!r})')
    return value


POSE_METAVAR = ('TX', 'TY', 'TZ', 'RX', 'RY', 'RZ')
_HUMAN_UNITS = 'Tx Ty Tz mm, Rx Ry Rz deg, R = Rz·Ry·Rx'


def _common(timeout_default: str, *, top: bool = False) -> argparse.ArgumentParser:
    """The common options, before the subcommand (``top``: their defaults set there) or after
    it (their defaults suppressed, so that one given before the subcommand is kept)."""
    common = argparse.ArgumentParser(add_help=False)
    group = common.add_argument_group('common options (before or after the command)')
    unset: Any = {} if top else {'default': argparse.SUPPRESS}
    group.add_argument('--json', action='store_true',
                       help='one JSON object on stdout instead of text', **unset)
    group.add_argument('--timeout', type=_positive, metavar='S',
                       help=f'give up after S seconds (default {timeout_default}); a goal '
                       'still running then is cancelled', **(unset or {'default': None}))
    group.add_argument('--domain', type=_domain, metavar='ID',
                       help='ROS domain id (default: ROS_DOMAIN_ID of the environment)',
                       **(unset or {'default': None}))
    return common


def _six_numbers(parser: argparse.ArgumentParser) -> None:
    """Tx Ty Tz (mm) Rx Ry Rz (deg) as six positionals ``tx`` ... ``rz``."""
    for name, unit in zip(POSE_METAVAR, ('mm',) * 3 + ('deg',) * 3, strict=True):
        parser.add_argument(name.lower(), metavar=name, type=_finite_number,
                            help=f'{name[0]}{name[1].lower()}, {unit}')


def human_pose(args: argparse.Namespace) -> list[float]:
    """The six numbers of :func:`_six_numbers` (mm, deg)."""
    return [getattr(args, name.lower()) for name in POSE_METAVAR]


def _pose_arguments(parser: argparse.ArgumentParser) -> None:
    _six_numbers(parser)
    kind = parser.add_mutually_exclusive_group()
    kind.add_argument('--relative-user', action='store_true',
                      help='a step from the current user position: the translation along the '
                      'user axes, the rotation about the pivot (object axes)')
    kind.add_argument('--relative-object', action='store_true',
                      help='a step in the object CS: translation along the object axes, '
                      'rotation about the pivot')
    kind.add_argument('--frame', choices=ABSOLUTE_FRAMES, default=USER_FRAME,
                      help='frame of an absolute goal: the platform in base, the platform in '
                      'the machine CS, or the object in the user CS (default %(default)s)')
    parser.add_argument('--tolerance', type=_non_negative, default=0.0, metavar='MM',
                        help='settle tolerance of the position, mm (default: the configured '
                        'one)')
    parser.add_argument('--speed-scale', type=_scale, default=None, metavar='S',
                        help='fraction (0, 1] of the current speeds and accelerations '
                        '(default 1)')


def _leaf(subparsers: Any, name: str, command: str, help_text: str) -> argparse.ArgumentParser:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name, help=help_text, description=help_text,
        parents=[_common(f'{default_timeout(command):g}')])
    parser.set_defaults(command=command)
    return parser


#: cell watch: redraws per second, and the most allowed.
WATCH_RATE, WATCH_RATE_MAX = 5.0, 30.0


def _watch_rate(text: str) -> float:
    value = _finite_number(text)
    if not 0.0 < value <= WATCH_RATE_MAX:
        raise argparse.ArgumentTypeError(f'{text}: must be > 0 and <= {WATCH_RATE_MAX:g} Hz')
    return value


def build_parser(description: str = '') -> argparse.ArgumentParser:
    """The command line of ``cell`` (every subcommand and its options; the common options
    --json, --timeout, --domain on each)."""
    parser = argparse.ArgumentParser(
        prog='cell', description=description or 'The operator\'s client of the positioning '
        'cell.', epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        parents=[_common(f'{GOAL_TIMEOUT:g} for move and home, {QUICK_TIMEOUT:g} otherwise',
                         top=True)])
    sub = parser.add_subparsers(dest='subcommand', required=True, metavar='COMMAND')

    cell_up = _leaf(sub, 'up', 'up', 'start the whole cell in the foreground (the nodes make '
                    'run starts; logs and bag in runs/<UTC time>/); Ctrl-C stops it')
    cell_up.add_argument('--params-file', metavar='YAML', default=None,
                         help='the parameter file of every node (default: the shipped '
                         'config/cell.yaml)')
    cell_up.add_argument('--record', action=argparse.BooleanOptionalAction, default=True,
                         help='record to an MCAP bag (default: on)')
    cell_up.add_argument('--live-view', action='store_true',
                         help='also the Foxglove live view (ws://127.0.0.1:8765)')
    cell_up.add_argument('--calibrator', action='store_true',
                         help='also the calibrator (the Calibrate action)')
    _leaf(sub, 'status', 'status', 'state, drives, and the user and machine positions '
          '(target and estimate)')
    move = _leaf(sub, 'move', 'move', f'move the platform ({_HUMAN_UNITS}; default: absolute, '
                 'the object in the user CS), with progress; Ctrl-C cancels')
    _pose_arguments(move)
    check = _leaf(sub, 'check', 'check', 'check a move without moving: valid, or the '
                  'violated limits; the margins')
    _pose_arguments(check)

    frames = sub.add_parser('frames', help='the user and object coordinate systems',
                            description='the user and object coordinate systems')
    frames_sub = frames.add_subparsers(dest='action', required=True, metavar='ACTION')
    _leaf(frames_sub, 'get', 'frames get', 'the user CS (in the machine CS) and the object CS '
          '(in the platform frame)')
    frames_set = _leaf(frames_sub, 'set', 'frames set', 'set the user and/or the object CS '
                       f'({_HUMAN_UNITS}); one left out stays as it is')
    frames_set.add_argument('--user', nargs=6, type=_finite_number, metavar=POSE_METAVAR,
                            help='the user CS in the machine CS')
    frames_set.add_argument('--object', nargs=6, type=_finite_number, metavar=POSE_METAVAR,
                            help='the object CS in the platform frame (its origin: the pivot)')
    define = _leaf(frames_sub, 'define', 'frames define', 'store a named user CS (in the '
                   f'machine CS) or object CS (in the platform frame; {_HUMAN_UNITS})')
    define.add_argument('kind', choices=('user', 'object'), help='user or object')
    define.add_argument('name', help='a letter, then letters, digits, _ or -; at most 32')
    _six_numbers(define)
    define.add_argument('--use', action='store_true', help='and make it the active one')
    use = _leaf(frames_sub, 'use', 'frames use', 'make named systems the active ones (a kind '
                'left out stays as it is)')
    use.add_argument('--user', metavar='NAME', help='the user CS to use')
    use.add_argument('--object', metavar='NAME', help='the object CS to use')

    watch = _leaf(sub, 'watch', 'watch', 'the live watch window: per axis commanded, measured, '
                  'deviation, tolerance (in/out in colour), uncertainty; q or Ctrl-C quits')
    watch.add_argument('--frame', choices=WATCH_FRAMES, default=USER_FRAME,
                       help='the frame of the deviation (default: user, the object in the '
                       'user CS; base: the platform in base)')
    watch.add_argument('--panel', action='store_true',
                       help='the coordinated cell instead (run_cell --cell): the coordinator, '
                       'the panel as its tracker measures it, the internal force by the load '
                       'cells, each positioner\'s state and drives')
    watch.add_argument('--rate', type=_watch_rate, default=WATCH_RATE, metavar='HZ',
                       help=f'redraws per second (default {WATCH_RATE:g}, at most '
                       f'{WATCH_RATE_MAX:g})')
    _leaf(sub, 'home', 'home', 'reference the drives if needed and move home, with progress; '
          'Ctrl-C cancels')
    _leaf(sub, 'stop', 'stop', 'controlled stop of whatever runs')
    jog = _leaf(sub, 'jog', 'jog', 'move one actuator by a step (outside the kinematics)')
    jog.add_argument('axis', choices=JOINT_NAMES, metavar='AXIS',
                     help=f'one of {", ".join(JOINT_NAMES)}')
    jog.add_argument('delta', type=_finite_number, metavar='DELTA',
                     help='the step: mm for a length, deg for an angle')
    speed = _leaf(sub, 'speed', 'speed', 'set the speeds and accelerations of moves (an '
                  'option left out stays; none: query)')
    speed.add_argument('--linear', type=_non_negative, metavar='MM_S', help='mm/s')
    speed.add_argument('--angular', type=_non_negative, metavar='DEG_S', help='deg/s')
    speed.add_argument('--linear-acceleration', type=_non_negative, metavar='MM_S2',
                       help='mm/s²')
    speed.add_argument('--angular-acceleration', type=_non_negative, metavar='DEG_S2',
                       help='deg/s²')

    limits = sub.add_parser('limits', help='the soft-limit boxes (machine CS, user CS)',
                            description='the soft-limit boxes (machine CS, user CS)')
    limits_sub = limits.add_subparsers(dest='action', required=True, metavar='ACTION')
    _leaf(limits_sub, 'get', 'limits get', 'the factory, machine and user boxes')
    _leaf(limits_sub, 'reset', 'limits reset', 'back to the factory: the machine box the '
          'factory box, no user box')
    limits_set = _leaf(limits_sub, 'set', 'limits set',
                       f'set the machine and user boxes ({_HUMAN_UNITS}; a bound "{NO_LIMIT}": '
                       'no limit); a side left out stays as it is')
    for side in ('machine-lower', 'machine-upper', 'user-lower', 'user-upper'):
        limits_set.add_argument(f'--{side}', nargs=6, type=_bound, metavar=POSE_METAVAR,
                                help=f'the {side.replace("-", " ")} bounds')
    return parser
