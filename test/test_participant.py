"""A node process makes its ROS context and DDS participant before it loads the node's modules
(positioning_cell.ros.participant, from its entry point positioning_cell.ros.entry), so that
the cell discovers it while those load (issue 24: each node answered 0.45-0.66 s after its
start, 0.38-0.52 s since; medians of 4 starts alternated, ad hoc); the hidden node that made
the participant stays while the node runs (withdrawn as the node's endpoints went out, it
sometimes held their discovery back by ~1 s: positioning_cell.ros.participant) and goes with
the process, and a stop while the modules load is honoured before the node is built.

Each check runs a node entry point in a child process whose node module cannot finish loading
until the test opens a gate: what the cell sees meanwhile is the participant of a process that
is still importing."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from cell_harness import Client, isolated_domain, waiting_for_file

from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.processes import cell_environment

pytestmark = pytest.mark.nodes

#: A node module that loads only once the gate file exists (and gives up, raising, after 60 s),
#: then says so; its node says when it is built.
GATED_MODULE = waiting_for_file('GATE', 'the gate never opened') + '''
print('modules loaded', flush=True)

import os

from rclpy.node import Node
from positioning_cell.ros.spin import NodeStart


def _build():
    print('node built', flush=True)
    node = Node('gated_node')

    def spinning():  # once spinning: the nodes its participant's graph holds
        timer.cancel()
        with open(os.environ['SPINNING'], 'w') as out:
            out.write(' '.join(sorted(node.get_node_names())))

    timer = node.create_timer(0.01, spinning)
    return node


main = NodeStart(_build, imports=())
'''

#: The child: the node entry point of the cell's executables, for the gated module.
ENTRY = 'from positioning_cell.ros.entry import _console\n_console("gated.node")()\n'
#: Bound on everything here (s): a start on a loaded 2-core machine takes a few seconds.
TIMEOUT_S = 60.0


@contextmanager
def gated_node(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], CellClient, Path]]:
    """The child started with the gate closed, a client on its domain, and the gate."""
    (tmp_path / 'gated').mkdir()
    (tmp_path / 'gated' / '__init__.py').touch()
    (tmp_path / 'gated' / 'node.py').write_text(GATED_MODULE)
    gate = tmp_path / 'gate'
    with isolated_domain() as domain, Client(domain, 'participant_test') as client:
        env = cell_environment(domain)
        env['PYTHONPATH'] = f'{tmp_path}:{env.get("PYTHONPATH", "")}'.rstrip(':')
        env['GATE'] = str(gate)
        env['SPINNING'] = str(tmp_path / 'spinning')
        child = subprocess.Popen([sys.executable, '-c', ENTRY], env=env, text=True,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            yield child, client, gate
        finally:
            if child.poll() is None:
                child.kill()
            child.communicate()


def _in_graph(client: CellClient, name: str) -> bool:
    return name in client.node.get_node_names()


def test_the_participant_is_discovered_while_the_modules_load(tmp_path: Path) -> None:
    with gated_node(tmp_path) as (child, client, gate):
        starter = f'_start_{child.pid}'
        wait_until(lambda: _in_graph(client, starter) or child.poll() is not None, TIMEOUT_S,
                   f'{starter} in the graph')
        assert child.poll() is None, child.communicate()
        assert not _in_graph(client, 'gated_node')  # its module is still loading
        gate.touch()
        spinning = tmp_path / 'spinning'
        wait_until(lambda: spinning.exists() or child.poll() is not None, TIMEOUT_S,
                   'gated_node spinning')
        assert child.poll() is None, child.communicate()
        wait_until(lambda: bool(spinning.read_text()), TIMEOUT_S, 'the node names written')
        assert starter in spinning.read_text().split()  # kept while the node runs
        wait_until(lambda: _in_graph(client, 'gated_node'), TIMEOUT_S, 'gated_node in the graph')
        assert _in_graph(client, starter)
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=TIMEOUT_S)
        assert child.returncode == 0, err[-3000:]
        assert out.splitlines() == ['modules loaded', 'node built'], out
        wait_until(lambda: not _in_graph(client, starter), TIMEOUT_S, f'{starter} to leave')


def test_a_stop_while_the_modules_load_ends_the_node_before_it_is_built(
        tmp_path: Path) -> None:
    with gated_node(tmp_path) as (child, client, gate):
        starter = f'_start_{child.pid}'
        wait_until(lambda: _in_graph(client, starter) or child.poll() is not None, TIMEOUT_S,
                   f'{starter} in the graph')
        child.send_signal(signal.SIGTERM)
        gate.touch()
        out, err = child.communicate(timeout=TIMEOUT_S)
        assert child.returncode == 0, err[-3000:]
        assert out.splitlines() == ['modules loaded'], out  # no node built
        assert 'Traceback' not in err, err[-3000:]
        wait_until(lambda: not _in_graph(client, starter), TIMEOUT_S, f'{starter} to leave')
