"""Loopback only by default: with the shipped Fast DDS profile (config/fastdds_loopback.xml) every
UDP and TCP socket of the cell's processes (the live view's WebSocket listener too), and of a
client in this process, is bound to 127.0.0.1 (``ss``), while the nodes still discover each
other and exchange messages."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from cell_harness import Client, ProcessGroup, isolated_domain, wait_until
from geometry_msgs.msg import PoseStamped

from positioning_cell import names
from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.config import config_path
from positioning_cell.ros.processes import (
    BOOTSTRAP_MARKER,
    Processes,
    bootstrapped_as_this,
    cell_environment,
)
from positioning_cell.ros.qos import STREAM_QOS

pytestmark = pytest.mark.nodes

PROFILE = config_path('fastdds_loopback.xml')
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'  # what Fast DDS 2.14 (Jazzy) reads
STARTUP = 60.0  # s; process start and discovery on a loaded 2-core VM (usually ~3 s)
NODES = ('leg_driver_node', 'pose_measurement_node', 'live_view_node')
#: The live view's WebSocket server on any free port (its TCP listener is checked too).
ARGS = {'live_view_node': ('-p', f'{names.NODE_LIVE_VIEW}:port:=0')}


def sockets(pids: set[int]) -> list[tuple[str, str]]:
    """(local address, ss line) of every UDP and TCP socket (any state) that one of ``pids``
    holds."""
    found = []
    for flags in ('-H', '-aunp'), ('-H', '-atnp'):
        out = subprocess.run(['ss', *flags], capture_output=True, text=True, check=True,
                             timeout=30).stdout
        for line in out.splitlines():
            owners = {int(p) for p in re.findall(r'pid=(\d+),', line)}
            if owners & pids:
                found.append((local_host(line), line.strip()))
    return found


def local_host(line: str) -> str:
    """The host part of the local address of an ``ss -H`` line (``127.0.0.1``, ``0.0.0.0``,
    ``*``, ``[::]``, ``127.0.0.1%lo``)."""
    address = line.split()[3]
    return address.rsplit(':', 1)[0]


def session(leader: int) -> set[int]:
    """``leader`` and every process in its session (the group's children, if any)."""
    pids = {leader}
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / 'stat').read_text()
            except OSError:
                continue
            fields = stat.rsplit(')', 1)[1].split()  # after "pid (comm)": state ppid pgrp sid
            if int(fields[3]) == leader:
                pids.add(int(entry.name))
    return pids


def not_loopback(found: list[tuple[str, str]]) -> list[str]:
    return [line for host, line in found if host != '127.0.0.1']


def test_the_parser_flags_every_non_loopback_binding() -> None:
    lines = {
        'UNCONN 0 0 127.0.0.1:7400 0.0.0.0:* users:(("python3",pid=7,fd=5))': '127.0.0.1',
        'UNCONN 0 0 0.0.0.0:36010 0.0.0.0:* users:(("python3",pid=7,fd=6))': '0.0.0.0',
        'UNCONN 0 0 192.0.2.2:48537 0.0.0.0:* users:(("python3",pid=7,fd=7))': '192.0.2.2',
        'UNCONN 0 0 239.255.0.1:7400 0.0.0.0:* users:(("python3",pid=7,fd=8))': '239.255.0.1',
        'LISTEN 0 128 [::]:22 [::]:* users:(("sshd",pid=9,fd=3))': '[::]',
        'LISTEN 0 128 *:80 *:* users:(("httpd",pid=9,fd=3))': '*',
    }
    for line, host in lines.items():
        assert local_host(line) == host
    assert len(not_loopback([(local_host(x), x) for x in lines])) == 5


def test_cell_environment_uses_the_shipped_profile_unless_the_caller_has_one(
        tmp_path: Path) -> None:
    env = cell_environment(7, {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                               'ROS_LOCALHOST_ONLY': '1'})
    assert env[PROFILE_VARIABLE] == str(PROFILE)
    # LOCALHOST would make rmw_fastrtps add a UDP transport on every interface.
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert 'ROS_LOCALHOST_ONLY' not in env
    assert env['ROS_DOMAIN_ID'] == '7'

    own = tmp_path / 'own_profile.xml'
    own.write_text('<dds/>')
    env = cell_environment(7, {PROFILE_VARIABLE: str(own)})
    assert env[PROFILE_VARIABLE] == str(own)  # the user's own profile wins
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    env = cell_environment(7, {PROFILE_VARIABLE: str(own),
                               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'})
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'  # widened deliberately


def test_a_child_of_this_interpreter_is_not_bootstrapped_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cell's environment drops the ROS wheels' bootstrap marker (another Python must set
    its own library path); a process of this interpreter's own venv, with this process's
    library path, gets the marker back and so does not re-execute itself: a child started by
    Processes sees the library path exactly as given (the bootstrapper's re-execution would
    add the venv's lib folder to it)."""
    monkeypatch.setenv(BOOTSTRAP_MARKER, '1')
    monkeypatch.setenv('LD_LIBRARY_PATH', str(tmp_path / 'lib'))
    env = cell_environment(7)
    assert BOOTSTRAP_MARKER not in env
    node = str(Path(sys.executable).parent / 'leg_driver_node')
    own = bootstrapped_as_this(env, node)
    assert own[BOOTSTRAP_MARKER] == '1' and own['LD_LIBRARY_PATH'] == str(tmp_path / 'lib')
    assert BOOTSTRAP_MARKER not in bootstrapped_as_this(env, '/usr/bin/python3')
    # a library path of the caller's own: the child's bootstrap sets it up
    assert BOOTSTRAP_MARKER not in bootstrapped_as_this(dict(env, LD_LIBRARY_PATH='/x'), node)
    with Processes(env, tmp_path) as procs:
        child = procs.start('python', label='child', extra_args=(
            '-c', 'import os; print("path", os.environ["LD_LIBRARY_PATH"])'))
        assert child.wait(timeout=60) == 0
        assert f'path {tmp_path / "lib"}\n' in procs.log('child')
    monkeypatch.delenv(BOOTSTRAP_MARKER)  # a process that was not bootstrapped: nothing to give
    assert BOOTSTRAP_MARKER not in bootstrapped_as_this(
        env, str(Path(sys.executable).parent / 'python'))


#: Two contexts (two participants) in one process, as a test process holds them: they discover
#: each other with discovery data through the transports.
TWO_PARTICIPANTS = """
import time
import rclpy
from rclpy.context import Context
contexts = [Context(), Context()]
nodes = []
for k, context in enumerate(contexts):
    rclpy.init(context=context)
    nodes.append(rclpy.create_node(f'participant_{k}', context=context))
deadline = time.monotonic() + 30.0
while 'participant_1' not in nodes[0].get_node_names() and time.monotonic() < deadline:
    time.sleep(0.02)
print('found' if {'participant_0', 'participant_1'} <= set(nodes[0].get_node_names())
      else f'not found: {nodes[0].get_node_names()}')
"""


def test_the_profile_parses_and_keeps_discovery_out_of_intra_process_delivery(
        tmp_path: Path) -> None:
    """Fast DDS reads the profile without a parser error (a misplaced element or a bad value
    is logged as XMLPARSER Error), delivers discovery data between participants of one
    process through the transports (USER_DATA_ONLY: the 2.14 lock cycle of FULL, the
    profile's comment), and two participants of one process still find each other."""
    settings = ET.parse(PROFILE).getroot().find('library_settings')
    assert settings is not None and settings.findtext('intraprocess_delivery') == 'USER_DATA_ONLY'
    with isolated_domain() as domain:
        result = subprocess.run([sys.executable, '-c', TWO_PARTICIPANTS], capture_output=True,
                                text=True, timeout=120, check=False,
                                env=cell_environment(domain), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert 'XMLPARSER' not in result.stdout + result.stderr, result.stderr
    # (a domain may still list a killed process's nodes for the 5 s lease: not an equality)
    assert result.stdout.strip() == 'found', result.stdout + result.stderr


def test_the_profile_carries_user_data_over_loopback_udp_alone() -> None:
    """One transport, UDPv4 on 127.0.0.1, and no shared memory: a process killed while its
    listener held a shared-memory port's lock stalls every writer to that port for seconds
    (the profile's comment; benchmarks/kill_stall.py)."""
    ns = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'
    root = ET.parse(PROFILE).getroot()
    descriptors = {d.findtext(f'{ns}transport_id'): d
                   for d in root.iter(f'{ns}transport_descriptor')}
    assert {k: d.findtext(f'{ns}type') for k, d in descriptors.items()} \
        == {'udp_loopback': 'UDPv4'}
    assert [a.text for a in descriptors['udp_loopback'].iter(f'{ns}address')] == ['127.0.0.1']
    (participant,) = root.iter(f'{ns}participant')
    assert [t.text for t in participant.iter(f'{ns}transport_id')] == ['udp_loopback']
    assert participant.findtext(f'{ns}rtps/{ns}useBuiltinTransports') == 'false'


def test_the_profile_has_writers_repair_a_dropped_message_within_the_monitors_window() -> None:
    """The default writer profile sends a heartbeat every 0.1 s while a reader has not
    acknowledged (Fast DDS: 3 s): a datagram dropped for a full receive buffer is asked for
    again at the next one, and a message later than the accuracy monitor's settle window or
    dwell can change which window settles a visit (benchmarks/repair_latency.py: at most
    0.16 s late with it, 3.0 s without)."""
    ns = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'
    root = ET.parse(PROFILE).getroot()
    (writer,) = [w for w in root.iter(f'{ns}data_writer')
                 if w.get('is_default_profile') == 'true']
    period = writer.find(f'{ns}times/{ns}heartbeatPeriod')
    assert period is not None
    seconds = (int(period.findtext(f'{ns}sec') or 0)
               + int(period.findtext(f'{ns}nanosec') or 0) * 1e-9)
    settle = MonitorSettings.from_file(config_path('cell.yaml')).settle
    assert 0 < seconds <= 0.1 < min(settle.window, settle.dwell)


@pytest.mark.skipif(shutil.which('ss') is None, reason='needs ss (iproute2)')
def test_no_cell_socket_is_bound_to_a_non_loopback_address(tmp_path: Path) -> None:
    if Path(os.environ[PROFILE_VARIABLE]).resolve() != PROFILE.resolve():
        pytest.skip(f'{PROFILE_VARIABLE} names the caller’s own profile')
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain, 'network_test') as client:
        assert group.env[PROFILE_VARIABLE] == str(PROFILE)
        truth = client.collect(PoseStamped, names.TRUE_POSE, STREAM_QOS)
        procs = {exe: group.start(exe, *ARGS.get(exe, ())) for exe in NODES}
        live_view = client.statuses(names.STATUS_LIVE_VIEW)
        # The truth needs the driver's joint states at pose_measurement: the two talk.
        wait_until(lambda: truth or group.dead(), STARTUP, 'the nodes exchanging messages')
        assert not group.dead(), {k: group.log(k)[-1500:] for k in group.dead()}
        wait_until(lambda: live_view, STARTUP, 'the live view serving')

        cell = sockets(set().union(*(session(p.pid) for p in procs.values())))
        own = sockets({os.getpid()})
        codes = group.stop()
    assert codes == dict.fromkeys(NODES, 0), {k: group.log(k)[-1500:] for k in codes}

    assert cell, 'no socket found for the cell processes: the check would prove nothing'
    assert not not_loopback(cell), 'cell sockets not on 127.0.0.1:\n' + '\n'.join(
        not_loopback(cell))
    for exe, proc in procs.items():  # each process has its own sockets, all checked
        assert any(f'pid={proc.pid},' in line for _, line in cell), exe
    websocket = [line for _, line in cell if line.startswith('LISTEN')
                 and f'pid={procs["live_view_node"].pid},' in line]
    assert websocket, 'the live view listens nowhere: the check would prove nothing'
    # Positive control: the client in this process (conftest's environment) is loopback too.
    assert own, 'no socket found for the test process'
    assert not not_loopback(own), 'test process sockets not on 127.0.0.1:\n' + '\n'.join(
        not_loopback(own))
