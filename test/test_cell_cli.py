"""The operator's client ``cell``, its pure parts (no running cell): the command line into
MoveCommand fields (mm → m, deg → rad, modes and frames), the exit code of every MoveOutcome
constant, the JSON and text of outcomes, checks, status, limits, speeds and jogs, the goal loop
against stand-in action handles (cancel on Ctrl-C and on the timeout), and ``--help`` of every
subcommand. The end-to-end runs against the cell are elsewhere."""

from __future__ import annotations

import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from positioning_cell_interfaces.action import MoveToPose
from positioning_cell_interfaces.msg import BoxLimits, MoveCommand, MoveOutcome, Speeds
from positioning_cell_interfaces.srv import CheckPose
from scipy.spatial.transform import Rotation

from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.frames.systems import (
    MACHINE_FRAME,
    OBJECT_FRAME,
    USER_FRAME,
    CoordinateSystems,
)
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.axis_ranges import AxisRange, AxisRanges
from positioning_cell.limits.boxes import AXES
from positioning_cell.limits.speed import Speeds as LibrarySpeeds
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.names import BASE_FRAME
from positioning_cell.ros import cell_messages as cm
from positioning_cell.ros import operator_messages as om
from positioning_cell.tools import cell
from positioning_cell.tools import cell_format as cf
from positioning_cell.tools import cell_parser as cp
from positioning_cell.tools.exits import Exit, exit_table
from positioning_cell.tools.interruption import Interrupted, Signals

MECH = Mechanism.default()


def parse(*argv: str) -> Any:
    return cp.build_parser().parse_args(list(argv))


def usage_error(*argv: str) -> None:
    with pytest.raises(SystemExit) as err:
        parse(*argv)
    assert err.value.code == Exit.USAGE


def command_of(*argv: str) -> MoveCommand:
    return cm.move_command(cf.move_request(parse(*argv)), Time(sec=3))


def quaternion_deg(rx: float, ry: float, rz: float) -> np.ndarray:
    """R = Rz·Ry·Rx (fixed axes x, then y, then z), w ≥ 0."""
    return Rotation.from_euler('xyz', [rx, ry, rz], degrees=True).as_quat(canonical=True)


def pose_of(command: MoveCommand) -> tuple[np.ndarray, np.ndarray]:
    p, o = command.pose.pose.position, command.pose.pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.x, o.y, o.z, o.w])


# -- the command line into MoveCommand ---------------------------------------------------------
def test_the_mode_constants_are_the_messages() -> None:
    assert cf.MODE_ABSOLUTE == MoveCommand.ABSOLUTE
    assert cf.MODE_RELATIVE_USER == MoveCommand.RELATIVE_USER
    assert cf.MODE_RELATIVE_OBJECT == MoveCommand.RELATIVE_OBJECT


@pytest.mark.parametrize('verb', ['move', 'check'])
def test_an_absolute_move_in_the_user_cs_by_default_in_si(verb: str) -> None:
    command = command_of(verb, '10', '-20', '30.5', '1', '-2', '3')
    p, q = pose_of(command)
    assert command.mode == MoveCommand.ABSOLUTE
    assert command.pose.header.frame_id == USER_FRAME
    assert command.pose.header.stamp.sec == 3
    np.testing.assert_allclose(p, [0.010, -0.020, 0.0305], rtol=0, atol=1e-15)
    np.testing.assert_allclose(q, quaternion_deg(1, -2, 3), atol=1e-12)
    assert command.tolerance == 0.0 and command.speed_scale == 0.0  # the configured ones


@pytest.mark.parametrize(('option', 'mode', 'frame'), [
    ('--relative-user', MoveCommand.RELATIVE_USER, USER_FRAME),
    ('--relative-object', MoveCommand.RELATIVE_OBJECT, OBJECT_FRAME),
    ('--frame=base', MoveCommand.ABSOLUTE, BASE_FRAME),
    ('--frame=machine', MoveCommand.ABSOLUTE, MACHINE_FRAME),
    ('--frame=user', MoveCommand.ABSOLUTE, USER_FRAME),
])
def test_modes_and_frames(option: str, mode: int, frame: str) -> None:
    command = command_of('move', '0', '0', '1', '0', '0', '90', option)
    assert (command.mode, command.pose.header.frame_id) == (mode, frame)
    np.testing.assert_allclose(pose_of(command)[1], quaternion_deg(0, 0, 90), atol=1e-12)


def test_tolerance_mm_and_speed_scale() -> None:
    command = command_of('move', '1', '2', '3', '0', '0', '0', '--tolerance', '0.05',
                         '--speed-scale', '0.25')
    assert command.tolerance == pytest.approx(5e-5, rel=1e-12)
    assert command.speed_scale == 0.25


def test_negative_numbers_are_coordinates() -> None:
    p, q = pose_of(command_of('move', '-1', '-2.5', '-.5', '-10', '0', '0'))
    np.testing.assert_allclose(p, [-0.001, -0.0025, -0.0005], atol=1e-15)
    np.testing.assert_allclose(q, quaternion_deg(-10, 0, 0), atol=1e-12)


def test_the_request_document_has_si_and_human() -> None:
    doc = cf.move_request(parse('move', '1', '2', '3', '4', '5', '6', '--relative-object'))\
        .document()
    assert doc['mode'] == MoveCommand.RELATIVE_OBJECT and doc['mode_name'] == 'relative_object'
    assert doc['frame'] == OBJECT_FRAME
    np.testing.assert_allclose(doc['pose']['human'], [1, 2, 3, 4, 5, 6], atol=1e-9)
    np.testing.assert_allclose(doc['pose']['pose6'][:3], [0.001, 0.002, 0.003])
    np.testing.assert_allclose(doc['pose']['pose6'][3:], np.radians([4, 5, 6]))


@pytest.mark.parametrize('argv', [
    ['move', '1', '2', '3', '4', '5'],                                   # five numbers
    ['move', '1', '2', '3', '4', '5', 'x'],                              # not a number
    ['move', '1', '2', '3', '4', '5', 'nan'],                            # not finite
    ['move', '1', '2', '3', '4', '5', '6', '--relative-user', '--relative-object'],
    ['move', '1', '2', '3', '4', '5', '6', '--relative-user', '--frame', 'base'],
    ['move', '1', '2', '3', '4', '5', '6', '--frame', 'object'],         # not absolute
    ['move', '1', '2', '3', '4', '5', '6', '--speed-scale', '0'],
    ['move', '1', '2', '3', '4', '5', '6', '--speed-scale', '1.5'],
    ['move', '1', '2', '3', '4', '5', '6', '--tolerance', '-1'],
    ['move', '1', '2', '3', '4', '5', '6', '--timeout', '0'],
    ['move', '1', '2', '3', '4', '5', '6', '--domain', '300'],
    ['jog', 'theta1', '1'],                                              # not a joint name
    ['jog', 'leg1_length', 'inf'],
    ['speed', '--linear', '-1'],
    ['frames', 'set', '--user', '1', '2', '3'],
    ['frames'], ['limits'], [],
    ['limits', 'set', '--user-upper', '1', '1', '1', '1', '1', 'nan'],
])
def test_usage_errors_exit_2(argv: list[str]) -> None:
    usage_error(*argv)


def test_common_options_and_default_timeouts() -> None:
    args = parse('status', '--json', '--domain', '42')
    assert (args.command, args.json, args.domain, args.timeout) == ('status', True, 42, None)
    assert cp.default_timeout('move') == cp.default_timeout('home') == 300.0
    assert cp.default_timeout('status') < 60.0
    assert parse('move', '0', '0', '0', '0', '0', '0', '--timeout', '5').timeout == 5.0
    assert {parse(*a).command for a in (['status'], ['move', *'000000'], ['check', *'000000'],
                                         ['frames', 'get'], ['frames', 'set'],
                                         ['frames', 'define', 'user', 'w', *'000000'],
                                         ['frames', 'use'], ['home'],
                                         ['stop'], ['jog', 'leg1_theta', '1'], ['speed'],
                                         ['limits', 'get'], ['limits', 'set'],
                                         ['limits', 'reset'], ['watch'])} == \
        set(cp.CLIENT_COMMANDS) == set(cell.COMMANDS) == set(cp.COMMANDS) - {'up'}


def test_common_options_are_taken_before_or_after_the_command() -> None:
    """`cell --json status` as well as `cell status --json`; given on both sides, the one
    after the command wins; not given, the defaults."""
    for line in (['--json', '--domain', '5', '--timeout', '3', 'status'],
                 ['status', '--json', '--domain', '5', '--timeout', '3'],
                 ['--json', 'status', '--domain', '5', '--timeout', '3']):
        args = parse(*line)
        assert (args.json, args.domain, args.timeout, args.command) == (True, 5, 3.0, 'status')
    args = parse('--timeout', '3', 'move', *'000000', '--timeout', '4')
    assert args.timeout == 4.0 and not args.json and args.domain is None
    args = parse('frames', 'get')
    assert (args.json, args.domain, args.timeout) == (False, None, None)
    with pytest.raises(SystemExit):
        parse('--domain', '500', 'status')


def test_up_options_and_the_nodes_they_start() -> None:
    """`cell up` starts what make run and the launch file start: the recorder first unless
    --no-record, the cell's nodes, the live view and the calibrator on request."""
    from positioning_cell import names
    from positioning_cell.tools.cell_up import chosen_nodes

    args = parse('up')
    assert (args.command, args.record, args.live_view, args.calibrator, args.params_file) == \
        ('up', True, False, False, None)
    default = chosen_nodes({'record': True, 'live_view': False, 'calibrator': False})
    assert default == [names.RECORDER, *names.CELL_NODES] == chosen_nodes({})
    args = parse('up', '--no-record', '--live-view', '--calibrator', '--domain', '7')
    assert chosen_nodes({'record': args.record, 'live_view': args.live_view,
                         'calibrator': args.calibrator}) == \
        [*names.CELL_NODES, names.LIVE_VIEW, names.CALIBRATOR]
    assert args.domain == 7


def test_up_refuses_a_bad_parameter_file_or_domain_and_starts_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from positioning_cell.tools.cell_up import up

    said: list[str] = []
    bad = tmp_path / 'bad.yaml'
    bad.write_text('positioner: [unclosed\n')
    assert up(parse('up', '--params-file', str(bad)), said.append, tmp_path / 'runs') == \
        Exit.USAGE
    assert said[-1].startswith('cell up: error:') and str(bad) in said[-1]
    monkeypatch.setenv('ROS_DOMAIN_ID', 'seven')
    assert up(parse('up'), said.append, tmp_path / 'runs') == Exit.USAGE
    assert "ROS_DOMAIN_ID='seven' is not a domain id" in said[-1]
    assert not (tmp_path / 'runs').exists()


def test_watch_options_are_checked() -> None:
    args = parse('watch')
    assert (args.command, args.frame, args.rate) == ('watch', 'user', cp.WATCH_RATE)
    assert parse('watch', '--frame', 'base', '--rate', '2.5').rate == 2.5
    for bad in (['--frame', 'tracker'], ['--rate', '0'], ['--rate', '31'], ['--rate', 'nan']):
        with pytest.raises(SystemExit) as exc:
            parse('watch', *bad)
        assert exc.value.code == Exit.USAGE, bad


def test_jog_lengths_in_mm_and_angles_in_degrees() -> None:
    for axis in JOINT_NAMES:
        name, delta = cf.jog_request(parse('jog', axis, '-1.5'))
        assert name == axis
        if axis.endswith('_length'):
            assert delta == pytest.approx(-1.5e-3) and cf.jog_unit(axis) == 'mm'
        else:
            assert delta == pytest.approx(math.radians(-1.5)) and cf.jog_unit(axis) == 'deg'
        assert cf.jog_human(axis, delta) == pytest.approx(-1.5)


class JogClient:
    """The operator client's jog, answering as the positioner does."""

    def __init__(self, answer: tuple[bool, str, str, float]) -> None:
        self.answer = answer

    def jog(self, axis: str, delta: float) -> tuple[bool, str, str, float]:
        return self.answer


def _jog(answer: tuple[bool, str, str, float], *line: str) -> tuple[str, str, Any]:
    from positioning_cell.tools import cell_commands

    out, err = io.StringIO(), io.StringIO()
    session = cell_commands.Session(JogClient(answer), Signals(),  # type: ignore[arg-type]
                                    cell.Output(False, out, err))
    report = cell_commands.cmd_jog(session, parse('jog', *line))
    cell.Output(False, out, err).emit('jog', report)
    return out.getvalue(), err.getvalue(), report


def test_a_refused_jog_says_why_and_echoes_no_position() -> None:
    """`cell jog leg1_length 500` printed "leg1_length: 0.0000 mm" before its refusal."""
    out, err, report = _jog((False, 'refused_limits', 'leg1_length would leave its range',
                             0.0), 'leg1_length', '500')
    assert out == '' and err == 'cell: refused_limits: leg1_length would leave its range\n'
    assert report.code == Exit.REFUSED and report.fields['position'] is None
    out, err, report = _jog((True, 'success', 'jogged leg1_length', 0.2015), 'leg1_length',
                            '1.5')
    assert out == 'leg1_length: 201.5000 mm (jogged leg1_length)\n' and err == ''


class LimitsClient:
    """The operator client's GetLimits and SetLimits, with a machine and a user box set."""

    def __init__(self) -> None:
        from positioning_cell.ros.operator_client import Limits

        self.factory = (np.full(6, -0.02), np.full(6, 0.02))
        self.current = Limits(self.factory, (np.full(6, -0.01), np.full(6, 0.01)),
                              (np.full(6, -0.005), np.full(6, 0.005)), [])
        self.sent: list[tuple[Any, Any]] = []

    def limits(self) -> Any:
        return self.current

    def set_limits(self, machine: Any, user: Any) -> tuple[bool, str]:
        self.sent.append((machine, user))
        self.current = self.current._replace(machine=machine, user=user)
        return True, 'limits set'


def test_limits_reset_sets_the_factory_box_and_no_user_box() -> None:
    from positioning_cell.tools import cell_commands

    client = LimitsClient()
    out = io.StringIO()
    session = cell_commands.Session(client, Signals(),  # type: ignore[arg-type]
                                    cell.Output(True, out, io.StringIO()))
    report = cell_commands.COMMANDS['limits reset'](session, parse('limits', 'reset'))
    assert report.code == Exit.OK and len(client.sent) == 1
    machine, user = client.sent[0]
    np.testing.assert_array_equal(machine[0], client.factory[0])
    np.testing.assert_array_equal(machine[1], client.factory[1])
    assert np.all(user[0] == -np.inf) and np.all(user[1] == np.inf)


class FramesClient:
    """The operator client's named coordinate systems, as the positioner keeps them."""

    def __init__(self) -> None:
        from positioning_cell.frames.named import NamedSystems

        self.named = NamedSystems()

    def define_coordinate_system(self, kind: str, name: str, value: Transform,
                                 activate: bool) -> tuple[bool, str]:
        self.named = self.named.defined(kind, name, value, activate=activate)
        return True, 'written'

    def select_coordinate_systems(self, user: str, obj: str) -> tuple[bool, str]:
        try:
            self.named = self.named.selected(user, obj)
        except Exception as err:  # the positioner answers with the reason
            return False, str(err)
        return True, 'written'

    def coordinate_systems(self) -> tuple[CoordinateSystems, str]:
        return self.named.active, '/f.yaml'

    def system_names(self) -> cf.SystemNames:
        n = self.named
        return cf.SystemNames(n.active_user, n.active_object, sorted(n.users),
                              sorted(n.objects))


def _frames(client: FramesClient, *line: str) -> Any:
    from positioning_cell.tools import cell_commands

    session = cell_commands.Session(client, Signals(),  # type: ignore[arg-type]
                                    cell.Output(True, io.StringIO(), io.StringIO()))
    args = parse('frames', *line)
    return cell_commands.COMMANDS[args.command](session, args)


def test_frames_define_and_use_name_the_systems_and_show_them() -> None:
    client = FramesClient()
    report = _frames(client, 'define', 'user', 'work', '10', '0', '0', '0', '0', '90', '--use')
    assert report.code == Exit.OK
    doc = report.fields['coordinate_systems']
    assert (doc['active_user'], doc['user_names']) == ('work', ['default', 'work'])
    np.testing.assert_allclose(doc['user']['human'], [10, 0, 0, 0, 0, 90], atol=1e-9)
    assert "user CS 'work' (in machine)" in report.text
    assert 'stored                   user: default, work; object: default' in report.text
    report = _frames(client, 'use', '--user', 'default')
    assert report.code == Exit.OK and report.fields['coordinate_systems']['active_user'] == \
        'default'
    refused = _frames(client, 'use', '--object', 'tool')
    assert refused.code == Exit.REFUSED and "no object system named 'tool'" in refused.error


def test_jog_exit_codes() -> None:
    assert cf.jog_exit_code(True, 'success') == Exit.OK
    assert cf.jog_exit_code(False, 'refused_busy') == Exit.REFUSED
    assert cf.jog_exit_code(False, 'aborted_fault') == Exit.ABORTED
    assert cf.jog_exit_code(False, '') == Exit.REFUSED
    assert cf.jog_exit_code(False, 'success') == Exit.REFUSED  # not a success after all


def test_speed_request_in_si_and_zero_keeps() -> None:
    request = cf.speed_request(parse('speed', '--linear', '20', '--angular-acceleration',
                                     '90'))
    assert request.linear_speed == pytest.approx(0.020)
    assert request.angular_acceleration == pytest.approx(math.pi / 2)
    assert request.angular_speed == request.linear_acceleration == 0.0
    assert request != LibrarySpeeds.keep() == cf.speed_request(parse('speed'))
    msg = om.speeds_msg(request)
    assert isinstance(msg, Speeds) and om.speeds(msg) == request
    doc = cf.speeds_document(request)
    assert doc['linear_speed_mm_s'] == pytest.approx(20.0)
    assert doc['angular_acceleration_deg_s2'] == pytest.approx(90.0)


def test_frames_request() -> None:
    user, obj = cf.frames_request(parse('frames', 'set', '--user', '10', '0', '0', '0', '0',
                                        '90'))
    assert obj is None and user is not None
    np.testing.assert_allclose(user.to_human(), [10, 0, 0, 0, 0, 90], atol=1e-9)
    systems = CoordinateSystems(user=user, object=Transform.from_human([0, 0, 5, 1, 0, 0]))
    back = cm.systems_of(om.systems_msg(systems.user, systems.object))
    np.testing.assert_allclose(back.user.to_pose6(), systems.user.to_pose6(), atol=1e-12)
    np.testing.assert_allclose(back.object.to_pose6(), systems.object.to_pose6(), atol=1e-12)


def test_limits_keep_what_is_left_out_and_none_is_no_limit() -> None:
    machine = cf.box_of([-0.01] * 3 + [-0.1] * 3, [0.01] * 3 + [0.1] * 3)
    user = cf.box_of([-math.inf] * 6, [math.inf] * 6)
    request = cf.limits_request(parse('limits', 'set', '--machine-lower', '-5', '-5', '-5',
                                      '-1', '-1', '-1', '--user-upper', '1', '2', '3', '4',
                                      '5', 'none', '--user-lower', 'none', 'NONE', '-1', '-1',
                                      '-1', '-1'))
    (m_low, m_high), (u_low, u_high) = request.merged(machine, user)
    np.testing.assert_allclose(m_low, [-0.005] * 3 + [math.radians(-1)] * 3)
    np.testing.assert_array_equal(m_high, machine[1])
    np.testing.assert_allclose(u_high[:5], [0.001, 0.002, 0.003, *np.radians([4, 5])])
    assert u_high[5] == math.inf and u_low[0] == u_low[1] == -math.inf
    np.testing.assert_allclose(u_low[2:], [-0.001, *np.radians([-1, -1, -1])])
    msg = cm.box_msg((u_low, u_high))
    assert isinstance(msg, BoxLimits)
    back = cm.box_of(msg)
    np.testing.assert_array_equal(back[0], u_low)
    np.testing.assert_array_equal(back[1], u_high)


# -- exit codes ----------------------------------------------------------------------------------
def outcome_constants() -> dict[str, int]:
    return {name: value for name, value in vars(MoveOutcome).items()
            if name.isupper() and isinstance(value, int) and not name.startswith('_')}


def expected_exit(name: str) -> Exit:
    if name == 'SUCCESS':
        return Exit.OK
    if name == 'OUT_OF_TOLERANCE':
        return Exit.NOT_ACHIEVED
    if name.startswith('REFUSED_'):
        return Exit.REFUSED
    # Uncommanded motion ends no command, but the drives were stopped: as an abort.
    assert name.startswith('ABORTED_') or name == 'UNCOMMANDED_MOTION', name
    return Exit.ABORTED


def test_every_move_outcome_constant_maps_to_an_exit_code() -> None:
    constants = outcome_constants()
    assert len(constants) == 23 and constants['ABORTED_STOP'] == 30
    # The message's constants are the positioner's result codes, one for one.
    assert {name.lower() for name in constants} == {r.value for r in ResultCode}
    for name, value in constants.items():
        assert cf.exit_code(name.lower(), value) == expected_exit(name), name
        assert cf.exit_code(name.lower()) == expected_exit(name), name
        assert cf.exit_code('', value) == expected_exit(name), name  # by number alone
        assert cf.Outcome(value, name.lower(), '').exit_code == expected_exit(name)


def test_an_unknown_outcome_counts_as_aborted() -> None:
    assert cf.exit_code('aborted_by_a_newer_positioner') == Exit.ABORTED
    assert cf.exit_code('') == Exit.ABORTED
    assert cf.exit_code('', 99) == Exit.ABORTED
    assert cf.exit_code('', 19) == Exit.REFUSED


def test_one_exit_code_table_documented_everywhere() -> None:
    """cell's docstring names the codes of the one table (tools/exits.py) with their JSON
    labels, and --help prints that table."""
    assert cell.__doc__ is not None
    table = cell.__doc__[cell.__doc__.index('Exit codes'):]
    doc_rows = [line.split()[:2] for line in table.splitlines() if line[:1].isdigit()]
    assert doc_rows == [[str(code.value), code.label] for code in Exit]
    assert [code.label for code in Exit] == ['success', 'out_of_tolerance', 'usage', 'refused',
                                             'aborted', 'not_there', 'interrupted']
    epilog = cp.build_parser().epilog or ''
    assert exit_table() in epilog
    assert all(f'{code.value:>3}  {code.label}' in epilog for code in Exit)


# -- outcomes in JSON and text -------------------------------------------------------------------
def outcome_msg(code: int = MoveOutcome.SUCCESS, name: str = 'success',
                uncertainty: list[float] | None = None,
                source: str = 'measured') -> MoveOutcome:
    msg = MoveOutcome(code=code, code_name=name, reason='settled within 10 µm',
                      attained_source=source)
    msg.attained.header.frame_id = BASE_FRAME
    msg.attained.pose.position.z = 0.19
    q = quaternion_deg(0, 0, 30)
    msg.attained.pose.orientation.x, msg.attained.pose.orientation.y = q[0], q[1]
    msg.attained.pose.orientation.z, msg.attained.pose.orientation.w = q[2], q[3]
    msg.attained_user.position.x, msg.attained_user.position.y = 0.010, -0.0025
    msg.position_error = [3e-6, -4e-6, 0.0]
    msg.orientation_error = [0.0, 0.0, math.radians(0.001)]
    msg.uncertainty = uncertainty if uncertainty is not None else [math.nan] * 6
    return msg


def test_outcome_json_is_complete_si_and_human_with_nan_as_null() -> None:
    outcome = cm.outcome_of(outcome_msg())
    text = cf.json_text(cf.command_document('move', outcome.exit_code, None,
                                            {'outcome': outcome.document()}))
    assert '\n' not in text and 'NaN' not in text
    doc = json.loads(text)
    assert list(doc)[:4] == ['command', 'exit_code', 'exit_name', 'error']
    assert (doc['command'], doc['exit_code'], doc['exit_name'], doc['error']) == \
        ('move', 0, 'success', None)
    o = doc['outcome']
    assert set(o) == {'code', 'code_name', 'reason', 'attained', 'attained_user',
                      'attained_source', 'position_error_m', 'orientation_error_rad',
                      'position_error_um', 'orientation_error_deg', 'uncertainty'}
    assert o['attained_source'] == 'measured'
    assert (o['code'], o['code_name'], o['reason']) == (0, 'success', 'settled within 10 µm')
    assert o['attained']['frame'] == BASE_FRAME
    assert o['attained']['position_m'] == [0.0, 0.0, 0.19]
    np.testing.assert_allclose(o['attained']['human'], [0, 0, 190, 0, 0, 30], atol=1e-9)
    np.testing.assert_allclose(o['attained']['pose6'][5], math.radians(30))
    np.testing.assert_allclose(o['attained_user']['human'], [10, -2.5, 0, 0, 0, 0], atol=1e-9)
    assert o['position_error_m'] == [3e-6, -4e-6, 0.0]
    assert o['position_error_um'] == pytest.approx(5.0)
    assert o['orientation_error_deg'] == pytest.approx(0.001)
    assert o['uncertainty'] == [None] * 6


def test_a_finite_uncertainty_is_kept_and_a_partial_one_nulled() -> None:
    u = [1e-6, 2e-6, 3e-6, math.nan, 1e-5, math.inf]
    doc = json.loads(cf.json_text(cm.outcome_of(outcome_msg(uncertainty=u)).document()))
    assert doc['uncertainty'] == [1e-6, 2e-6, 3e-6, None, 1e-5, None]


def test_json_text_is_strict_json() -> None:
    doc = {'a': np.float64('nan'), 'b': np.array([1.0, -np.inf]), 'c': (np.int64(3), True),
           'd': {'e': np.bool_(False)}}
    assert json.loads(cf.json_text(doc)) == {'a': None, 'b': [1.0, None], 'c': [3, True],
                                             'd': {'e': False}}


def test_a_command_document_keeps_its_own_four_keys() -> None:
    doc = cf.command_document('status', 5, 'gone', {'code': 'success', 'exit_code': 0})
    assert doc['exit_code'] == 5 and doc['code'] == 'success' and doc['error'] == 'gone'


def test_outcome_text() -> None:
    text = cm.outcome_of(outcome_msg(uncertainty=[1e-6] * 3 + [1e-5] * 3)).text()
    lines = text.splitlines()
    assert lines[0] == 'success (0): settled within 10 µm'
    assert 'user position' in lines[1] and '10.0000' in lines[1] and '-2.5000' in lines[1]
    assert lines[1].rstrip().endswith('deg  (measured)') and ' mm ' in lines[1]
    assert 'error' in lines[2] and '5.0 µm' in lines[2] and '0.00100 deg' in lines[2]
    assert 'uncertainty' in lines[3] and '1.0 1.0 1.0 µm' in lines[3]
    assert 'uncertainty' not in cm.outcome_of(outcome_msg()).text()  # NaN: not measured


def test_a_refusal_says_why_and_where_the_platform_stands() -> None:
    outcome = cm.outcome_of(outcome_msg(MoveOutcome.REFUSED_LIMITS, 'refused_limits',
                                        source='estimated'))
    assert not outcome.moved and outcome.exit_code == Exit.REFUSED
    lines = outcome.text().splitlines()
    assert lines[0] == 'refused_limits (11): settled within 10 µm'
    assert 'user position' in lines[1] and lines[1].endswith('(estimated, nothing moved)')
    assert 'error' in lines[2] and '5.0 µm' in lines[2]  # how far the goal is from there


def test_an_outcome_without_a_pose_says_so_and_shows_no_zeros() -> None:
    """No pose estimate and no tracker reading (attained_source empty): not "user position
    0.0000 ... error 0.0 µm", as a stopped move once printed."""
    msg = MoveOutcome(code=MoveOutcome.ABORTED_STOP, code_name='aborted_stop', reason='stopped')
    msg.position_error = [math.nan] * 3
    msg.orientation_error = [math.nan] * 3
    outcome = cm.outcome_of(msg)
    assert outcome.text() == ('aborted_stop (30): stopped\n'
                              '  ended at: not known (no pose estimate, no tracker reading)')
    doc = json.loads(cf.json_text(outcome.document()))
    assert doc['attained'] is None and doc['attained_user'] is None
    assert doc['attained_source'] is None and doc['position_error_m'] == [None] * 3


def test_a_stopped_move_shows_where_it_ended_and_its_error() -> None:
    outcome = cm.outcome_of(outcome_msg(MoveOutcome.ABORTED_STOP, 'aborted_stop'))
    assert outcome.exit_code == Exit.ABORTED
    lines = outcome.text().splitlines()
    assert lines[1].startswith('  user position') and lines[1].endswith('(measured)')
    assert '10.0000' in lines[1] and '5.0 µm' in lines[2]


def test_a_pose_that_is_not_a_rotation_has_no_human_numbers() -> None:
    doc = cf.pose_document([0, 0, 0], [0, 0, 0, 0])
    assert doc['pose6'] is None and doc['human'] is None
    assert json.loads(cf.json_text(doc))['quaternion_xyzw'] == [0, 0, 0, 0]


def test_progress_line() -> None:
    line = cf.progress_line('moving', 0.5, [0.0, 3e-6, 4e-6], width=10)
    assert line == 'moving     [#####.....]  50%  |Δp| 5.0 µm'
    assert cf.progress_line('settling', 7.0, width=4) == 'settling   [####] 100%'
    assert cf.progress_line('', math.nan, width=2) == '...        [..]   0%'


# -- check, status, limits, speeds ---------------------------------------------------------------
RANGES = AxisRanges((0.0,) * 6, tuple(
    AxisRange(axis, -0.001, 0.004, f'user.{axis}_min', 'span limit') for axis in AXES))


def check_response(valid: bool) -> Any:
    response = CheckPose.Response(valid=valid, duration=2.5 if valid else 0.0)
    response.goal.header.frame_id = BASE_FRAME
    response.goal.pose.position.z = 0.19
    if not valid:
        response.validity.bits = 2 | 128
        response.validity.bit_names = ['stroke', 'machine_limits']
        response.validity.violations = ['factory: leg 1 at 0.2210 m above 0.2200 m',
                                        'machine limits: Tx 15 mm above 10 mm']
    response.validity.margin_names = ['stroke', 'machine_limits']
    response.validity.margins = [0.001, -0.005 if not valid else 0.002]
    return response


def test_check_valid_and_invalid() -> None:
    valid = cm.check_of(check_response(True))
    assert valid.exit_code == Exit.OK
    assert valid.text().splitlines()[0] == 'valid: the move takes 2.50 s'
    invalid = cm.check_of(check_response(False))
    assert invalid.exit_code == Exit.REFUSED
    text = invalid.text()
    assert text.startswith('not valid (bits 130): stroke, machine_limits')
    assert '  - machine limits: Tx 15 mm above 10 mm' in text
    assert 'machine_limits  -0.005' in text
    doc = json.loads(cf.json_text(invalid.document()))
    assert doc['valid'] is False and doc['bits'] == 130
    assert doc['bit_names'] == ['stroke', 'machine_limits'] and len(doc['violations']) == 2
    assert doc['margins'] == [{'name': 'stroke', 'value': 0.001},
                              {'name': 'machine_limits', 'value': -0.005}]
    assert doc['goal']['frame'] == BASE_FRAME and doc['goal']['human'][2] == pytest.approx(190)
    assert doc['duration_s'] == 0.0
    assert doc['axis_ranges']['valid'] is False  # an answer without ranges: none shown


def test_check_and_status_show_the_axis_ranges() -> None:
    response = check_response(True)
    response.axis_ranges = om.axis_ranges_msg(RANGES, 'work', Time(sec=5))
    report = cm.check_of(response)
    assert report.axis_ranges == RANGES
    text = report.text()
    assert 'axis ranges (each user axis with the other five held; mm, deg) from the goal:' \
        in text
    assert '  Ty     -1.000 mm ..     4.000 mm  (low: user.Ty_min; high: span limit)' in text
    doc = json.loads(cf.json_text(report.document()))['axis_ranges']
    assert doc['valid'] is True and doc['ranges'][1] == {
        'axis': 'Ty', 'low': -0.001, 'high': 0.004, 'low_binding': 'user.Ty_min',
        'high_binding': 'span limit'}
    status = cf.StatusReport(positioner={'state': 'idle'}, axis_ranges=RANGES)
    assert '  Rx  ' in status.text() and 'from the current user position:' in status.text()
    assert json.loads(cf.json_text(status.document()))['axis_ranges']['pose'] == [0.0] * 6
    none = cf.StatusReport(positioner={'state': 'idle'},
                           axis_ranges=AxisRanges.unknown('no pose estimate yet'))
    assert '  none: no pose estimate yet' in none.text()
    assert json.loads(cf.json_text(none.document()))['axis_ranges']['pose'] == [None] * 6


def test_status_positions_in_the_machine_and_user_cs() -> None:
    home = MECH.home_position
    systems = CoordinateSystems(user=Transform.from_human([10, 0, 0, 0, 0, 0]))
    report = cf.StatusReport(
        positioner={'state': 'settled', 'reason': 'within 5 µm', 'mode': 'model',
                    'code': 'success', 'referenced': 'True'},
        driver={'enabled': 'true', 'state': 'holding'},
        target=(home + [0.001, 0, 0], quaternion_deg(0, 0, 0)),
        estimate=(home + [0.0011, 0, 0], quaternion_deg(0, 0, 0.5)),
        systems=systems, mechanism=MECH)
    doc = json.loads(cf.json_text(report.document()))
    assert (doc['state'], doc['reason'], doc['mode'], doc['code']) == \
        ('settled', 'within 5 µm', 'model', 'success')
    assert doc['referenced'] is True and doc['drives_enabled'] is True
    assert doc['driver_state'] == 'holding'
    positions = doc['positions']
    np.testing.assert_allclose(positions['machine']['target']['human'], [1, 0, 0, 0, 0, 0],
                               atol=1e-9)
    np.testing.assert_allclose(positions['user']['target']['human'], [-9, 0, 0, 0, 0, 0],
                               atol=1e-9)
    np.testing.assert_allclose(positions['user']['estimated']['human'],
                               [-8.9, 0, 0, 0, 0, 0.5], atol=1e-9)
    np.testing.assert_allclose(positions['base']['target']['position_m'], home + [0.001, 0, 0])
    text = report.text()
    assert 'state       settled: within 5 µm' in text and 'enabled yes (holding)' in text
    assert text.count('target') == 2 and text.count('estimated') == 2


def test_status_shows_the_last_code_the_calibration_and_the_measured_pose() -> None:
    """The last command's code and words however long ago it ended (the event's `code` is
    empty in every later status: `cell status` showed "last code -" always), the calibration
    in force, and the tracker's pose with its age and uncertainty."""
    home = MECH.home_position
    sigma = np.array([2e-6, 3e-6, 1.5e-6, 1e-5, 1e-5, 1e-5])
    report = cf.StatusReport(
        positioner={'state': 'idle', 'reason': 'ready', 'mode': 'model', 'code': '',
                    'last_code': 'refused_limits', 'last_reason': 'machine limits: Tx 3 mm',
                    'calibration': 'runs/x/calibration.yaml', 'referenced': 'True',
                    'user_cs_name': 'work', 'object_cs_name': 'default'},
        estimate=(home, quaternion_deg(0, 0, 0)), mechanism=MECH,
        measured=cf.MeasuredValues((home + [0.0002, 0, 0], quaternion_deg(0, 0, 0)), sigma,
                                   1000.0), now=1000.25)
    text = report.text()
    assert 'last code   refused_limits: machine limits: Tx 3 mm' in text
    assert 'calibration runs/x/calibration.yaml' in text
    assert "systems     user 'work', object 'default'" in text
    assert text.count(' measured   ') == 2  # user and machine CS
    assert 'by the tracker, 0.25 s ago; uncertainty x y z 2.0 3.0 1.5 µm' in text
    doc = json.loads(cf.json_text(report.document()))
    assert (doc['last_code'], doc['calibration']) == ('refused_limits',
                                                      'runs/x/calibration.yaml')
    assert doc['measured_age_s'] == pytest.approx(0.25)
    np.testing.assert_allclose(doc['positions']['machine']['measured']['human'],
                               [0.2, 0, 0, 0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(doc['measured_uncertainty'], sigma)


def test_status_without_the_mechanism_or_a_target() -> None:
    report = cf.StatusReport(positioner={'state': 'idle'}, estimate=(MECH.home_position,
                             [0, 0, 0, 1]), notes=['no target'])
    doc = report.document()
    assert doc['referenced'] is None and doc['drives_enabled'] is None
    assert doc['positions']['machine'] == {'target': None, 'estimated': None,
                                           'measured': None}
    assert doc['measured_age_s'] is None and 'note: no target' in report.text()
    assert doc['positions']['base']['estimated'] is not None
    assert 'unknown' in report.text() and 'note: no target' in report.text()
    assert json.loads(cf.json_text(doc))['coordinate_systems'] is None


def test_parse_bool() -> None:
    assert [cf.parse_bool(t) for t in ('True', 'false', '1', 'no', 'maybe', None)] == \
        [True, False, True, False, None, None]


def test_limits_text_and_json() -> None:
    factory = cf.box_of([-0.02] * 3 + [-0.5] * 3, [0.02] * 3 + [0.5] * 3)
    user = cf.box_of([-math.inf] * 6, [math.inf] * 6)
    text = cf.limits_text(factory, factory, user, ['stroke 0.18..0.22 m'])
    assert 'Tx mm' in text and 'Rz deg' in text and '-20.000' in text and '28.6479' in text
    assert text.count(cf.NO_LIMIT) == 12 and text.endswith('stroke 0.18..0.22 m')
    doc = json.loads(cf.json_text(cf.limits_document(factory, factory, user)))
    assert doc['user']['lower'] == [None] * 6
    assert doc['factory']['upper_human'][0] == pytest.approx(20.0)


def test_speeds_text() -> None:
    text = cf.speeds_text(LibrarySpeeds(0.01, math.radians(5), 0.05, math.radians(20)),
                          LibrarySpeeds(0.05, math.radians(30), 0.2, math.radians(100)))
    assert 'linear speed' in text and '10.000 mm/s' in text and '(max 50.000)' in text
    assert '5.000 deg/s' in text and '(max 100.000)' in text


# -- the goal loop, against stand-ins of rclpy's action client ------------------------------------
@dataclass
class Done:
    value: Any

    def done(self) -> bool:
        return True

    def result(self) -> Any:
        return self.value


class Pending:
    def done(self) -> bool:
        return False


class Handle:
    """A goal handle whose result comes once the goal is cancelled (or at once)."""

    def __init__(self, accepted: bool = True, outcome: MoveOutcome | None = None,
                 at_once: bool = False) -> None:
        self.accepted = accepted
        self.cancels = 0
        self.outcome = outcome or outcome_msg(MoveOutcome.ABORTED_STOP, 'aborted_stop')
        self.at_once = at_once

    def get_result_async(self) -> Any:
        handle = self

        class Result:
            def done(self) -> bool:
                return handle.at_once or handle.cancels > 0

            def result(self) -> Any:
                response = MoveToPose.Impl.GetResultService.Response(status=5)
                response.result.outcome = handle.outcome
                return response

        return Result()

    def cancel_goal_async(self) -> Any:
        self.cancels += 1
        return Pending()


class Action:
    """A GoalClient's stand-in: its action client and the spin of its answers."""

    def __init__(self, handle: Handle | None, on_send: Callable[[], None] = lambda: None):
        self.handle = handle
        self.on_send = on_send
        self.action = self

    def spin_once(self, timeout: float) -> None:
        time.sleep(timeout)

    def send_goal_async(self, goal: Any, feedback_callback: Any = None) -> Any:
        self.on_send()
        feedback_callback(MoveToPose.Impl.FeedbackMessage(
            feedback=MoveToPose.Feedback(phase_name='moving', progress=0.5)))
        return Pending() if self.handle is None else Done(self.handle)


@dataclass
class Loop:
    """What the goal loop is given: the signals it counts, the timeout, and the note and
    progress lines it writes (on ``err``)."""

    timeout: float = 5.0
    signals: Signals = field(default_factory=Signals)
    err: io.StringIO = field(default_factory=io.StringIO)

    def drive(self, action: Action) -> cf.GoalRun:
        out = cell.Output(False, io.StringIO(), self.err)
        with self.signals.deferred():
            return cm.drive(action, None, self.timeout, lambda: self.signals.count, out.note,
                            lambda f: out.progress(f'{f.phase_name} {f.progress}'))


def test_a_goal_that_ends_by_itself() -> None:
    s = Loop()
    run = s.drive(Action(Handle(outcome=outcome_msg(), at_once=True)))
    assert run.accepted and not run.cancelled and run.exit_code == Exit.OK
    assert run.goal_status == 5 and run.outcome is not None
    assert s.err.getvalue() == ''  # not a terminal: no progress bar
    assert set(run.fields()) == {'accepted', 'cancelled', 'cancel_cause', 'goal_status',
                                 'outcome'}


def test_ctrl_c_cancels_and_the_result_is_awaited() -> None:
    s = Loop()
    handle = Handle()
    run = s.drive(Action(handle, on_send=lambda: s.signals(2, None)))  # SIGINT, deferred
    assert handle.cancels == 1 and run.cancelled and run.cancel_cause == 'interrupt'
    assert run.outcome is not None and run.outcome.code_name == 'aborted_stop'
    assert run.exit_code == Exit.ABORTED and 'cancelling' in s.err.getvalue()
    assert run.text().splitlines()[0] == 'cancelled (Ctrl-C)'


def test_the_timeout_cancels() -> None:
    s = Loop(timeout=0.05)
    handle = Handle()
    run = s.drive(Action(handle))
    assert handle.cancels == 1 and run.cancel_cause == 'timeout'
    assert run.exit_code == Exit.ABORTED


def test_a_second_ctrl_c_stops_waiting() -> None:
    s = Loop()

    def twice() -> None:
        s.signals(2, None)
        s.signals(2, None)

    run = s.drive(Action(Handle(), on_send=twice))
    assert run.outcome is None and run.exit_code == Exit.INTERRUPTED and run.error


def test_a_rejected_goal_is_refused() -> None:
    s = Loop()
    run = s.drive(Action(Handle(accepted=False)))
    assert run.accepted is False and run.exit_code == Exit.REFUSED


def test_no_outcome_counts_as_aborted() -> None:
    s = Loop()
    run = s.drive(Action(Handle(outcome=MoveOutcome(), at_once=True)))
    assert run.outcome is None and run.exit_code == Exit.ABORTED
    assert run.error is not None and 'no outcome' in run.error


def test_no_answer_after_the_cancel_is_not_there(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cm, 'CANCEL_WAIT', 0.05)
    s = Loop(timeout=0.05)
    run = s.drive(Action(None))  # the goal's acceptance never comes
    assert run.accepted is None and run.exit_code == Exit.NOT_THERE


def test_signals_raise_outside_a_goal() -> None:
    signals = Signals()
    with pytest.raises(Interrupted):
        signals(2, None)
    with signals.deferred():
        signals(15, None)
    assert signals.count == 2


def test_output_one_json_line_or_text() -> None:
    out, err = io.StringIO(), io.StringIO()
    cell.Output(True, out, err).emit('stop', cell.Report(Exit.REFUSED, {'success': False},
                                                         'text', 'refused: busy'))
    assert json.loads(out.getvalue()) == {'command': 'stop', 'exit_code': 3,
                                          'exit_name': 'refused', 'error': 'refused: busy',
                                          'success': False}
    assert out.getvalue().count('\n') == 1 and 'refused: busy' in err.getvalue()
    out = io.StringIO()
    cell.Output(False, out, io.StringIO()).emit('stop', cell.Report(Exit.OK, {}, 'stopped'))
    assert out.getvalue() == 'stopped\n'


# -- --help --------------------------------------------------------------------------------------
HELPS = [[], ['status'], ['move'], ['check'], ['frames'], ['frames', 'get'], ['frames', 'set'],
         ['frames', 'define'], ['frames', 'use'],
         ['home'], ['stop'], ['jog'], ['speed'], ['limits'], ['limits', 'get'],
         ['limits', 'set'], ['limits', 'reset'], ['watch'], ['up']]


def test_help_of_cell_and_of_every_subcommand_exits_0(
        capsys: pytest.CaptureFixture[str]) -> None:
    """Every subcommand's --help, in this process (the installed `cell --help` runs in
    test_package)."""
    parser = cp.build_parser()
    for args in HELPS:
        with pytest.raises(SystemExit) as done:
            parser.parse_args([*args, '--help'])
        assert done.value.code == 0, args
        assert capsys.readouterr().out.startswith('usage: cell'), args
    assert {c.split()[0] for c in cp.COMMANDS} == {a[0] for a in HELPS if a}
