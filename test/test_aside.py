"""positioning_cell.ros.spin.aside_node: a node's callbacks that never wait, on a node beside
it spun on an events executor of its own (the positioner's pose and diagnostics timers), run
as every node of the cell is run and gone with it."""

from __future__ import annotations

import subprocess
import sys

import pytest
from cell_harness import isolated_domain

from positioning_cell.ros.processes import cell_environment

pytestmark = pytest.mark.nodes

#: A node on the positioner's kind of executor (threads) with a timer of its own and one on
#: a node beside it, run as the cell's nodes are run (spin.run); the beside timer ends the
#: run after a few calls (the owner's timer ends it with exit status 3 after 10 s without).
#: Prints the exit status, the beside node's name, the threads its timer ran in, where the
#: owner's ran, and how many timers the beside node still had after the run (0: destroyed
#: with its owner).
PROBE = '''
import threading
import time
from rclpy.node import Node
from positioning_cell.ros.spin import NodeStart, Spin, aside_node, run

seen = {'own': set(), 'aside': set()}
made = []


class Probe(Node):
    def __init__(self):
        super().__init__('aside_probe')
        self.exit_status = None
        self.calls, self.started = 0, None
        helper = aside_node(self, 'outputs', [(0.01, self._aside)])
        made.append((helper, helper.get_name()))
        self.create_timer(0.01, self._own)

    def _own(self):
        seen['own'].add(threading.current_thread().name)
        if self.started is None:
            self.started = time.monotonic()
        elif time.monotonic() - self.started > 10.0:  # the beside timer never ran
            self.exit_status = 3

    def _aside(self):
        seen['aside'].add(threading.current_thread().name)
        self.calls += 1
        if self.calls >= 5 and seen['own']:
            self.exit_status = 0


status = run(NodeStart(Probe, Spin.THREADS, threads=2, imports=()))
print(status, made[0][1], '|'.join(sorted(seen['aside'])),
      'main' if seen['own'] <= {'MainThread'} else 'pool', len(list(made[0][0].timers)),
      sep=';')
'''


def test_a_nodes_beside_node_spins_in_a_thread_of_its_own_and_goes_with_it() -> None:
    with isolated_domain() as domain:
        done = subprocess.run([sys.executable, '-c', PROBE], env=cell_environment(domain),
                              capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    status, name, aside_threads, own, timers_left = done.stdout.strip().split(';')
    assert status == '0' and name == '_aside_probe__outputs'
    # the beside node's timer in its own executor's thread, not in the owner's executor
    assert aside_threads == 'spin _aside_probe__outputs', done.stdout
    assert own == 'pool'  # the owner's timer in its multi-threaded executor's pool
    assert timers_left == '0'  # destroyed at the end of the run, with its owner
