"""positioning_cell.ros.unspun: the nodes no executor spins, which the readers of a node take
their messages through, are destroyed explicitly with it (by spin's teardown), not left to
the garbage collection after rclpy's shutdown."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator

import pytest
import rclpy
from cell_harness import isolated_domain
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

from positioning_cell.polling import wait_until
from positioning_cell.ros.latest import Reader, SourceReader
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.senders import IdentifiedSubscription
from positioning_cell.ros.unspun import acts_for, destroy_unspun

pytestmark = pytest.mark.nodes


@pytest.fixture
def context() -> Iterator[Context]:
    with isolated_domain() as domain:
        ctx = Context()
        rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        try:
            yield ctx
        finally:
            rclpy.try_shutdown(context=ctx)


def test_an_owners_unspun_nodes_go_with_destroy_unspun(context: Context) -> None:
    owner, other = Node('unspun_owner', context=context), Node('unspun_other', context=context)
    try:
        readers = [Reader(owner, JointState, '/unspun/a'),
                   SourceReader(owner, JointState, '/unspun/b', '/somebody'),
                   IdentifiedSubscription(owner, JointState, '/unspun/c', 10)]
        Reader(other, JointState, '/unspun/a')
        helpers = [r._node for r in (readers[0], readers[2])] + [readers[1]._sub._node]
        assert all(len(list(h.subscriptions)) == 1 for h in helpers)
        readers[0].destroy()  # one destroyed by its reader first: not destroyed twice
        assert destroy_unspun(owner) == 2
        assert all(list(h.subscriptions) == [] for h in helpers)
        assert destroy_unspun(owner) == 0
        readers[1].destroy()  # already gone: nothing happens
        assert destroy_unspun(other) == 1  # another owner's, apart
    finally:
        other.destroy_node()
        owner.destroy_node()


def test_a_readers_subscription_is_its_owners_in_the_graph(context: Context) -> None:
    """What the graph shows of a reader: a subscription of a node that acts for its owner (a
    tool waiting for a node to subscribe counts it), and for no other node."""
    owner, client = Node('acts_owner', context=context), Node('acts_client', context=context)
    try:
        Reader(owner, JointState, '/unspun/acts')
        infos = wait_until(lambda: client.get_subscriptions_info_by_topic('/unspun/acts'), 10.0,
                           'the reader in the graph')
        assert [acts_for(i.node_name, 'acts_owner') for i in infos] == [True]
        assert not any(acts_for(i.node_name, n) for i in infos for n in ('acts', 'owner',
                                                                           'acts_client'))
        assert acts_for('acts_owner', 'acts_owner')
    finally:
        destroy_unspun(owner)
        client.destroy_node()
        owner.destroy_node()


#: A node with a reader, run as every node of the cell is run (spin.run), that ends its own
#: run; then whether its reader's node was destroyed before run returned.
PROBE = '''
import sys
from rclpy.node import Node
from sensor_msgs.msg import JointState
from positioning_cell.ros import unspun
from positioning_cell.ros.latest import Reader
from positioning_cell.ros.spin import NodeStart, run

made = []


class Probe(Node):
    def __init__(self):
        super().__init__('unspun_probe')
        self.exit_status = None
        self.reader = Reader(self, JointState, '/unspun/probe')
        made.append(self.reader._node)
        self.create_timer(0.01, self._tick)

    def _tick(self):
        self.exit_status = 0


status = run(NodeStart(Probe, imports=()))
print(status, len(list(made[0].subscriptions)), len(unspun._unspun))
'''


def test_a_nodes_run_destroys_its_readers_nodes() -> None:
    with isolated_domain() as domain:
        done = subprocess.run([sys.executable, '-c', PROBE], env=cell_environment(domain),
                              capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ['0', '0', '0'], done.stdout
