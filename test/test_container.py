"""cell_container: the cell's nodes in one process (ROS 2's composition pattern). Started with
config/cell.yaml as the single nodes are; every hosted node on the graph, the positioner homes
and makes one small move through its service, then SIGTERM stops the whole process cleanly:
exit 0, no traceback or C++ abort printed, within a bound. The move runs with the positioner's
liveness watches at the lax end of their ranges (as the fault trials' baseline does): the
composed cell's nodes share one interpreter, and on a loaded machine a 0.2 s gap in the driver's
readings there is a known limit of composition (docs/howto/run.md, measured by
benchmarks/idle_cpu.py --one-process), not what this test judges. Bad node names are refused before
anything starts (exit 2, naming them). Multi-process tier (the container is one process;
benchmarks/idle_cpu.py --one-process measures what it costs)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from cell_harness import Client, ProcessGroup, executable, isolated_domain, wait_until
from geometry_msgs.msg import PoseStamped
from workspace import MECH

from positioning_cell import names
from positioning_cell.procedures.fault_trials import LAX_LIVENESS
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.qos import STREAM_QOS
from positioning_cell.testing.stops import CRASH_SIGNS

pytestmark = [pytest.mark.nodes, pytest.mark.timing]

#: The container (its four nodes, numba kernels loaded from the disk cache) comes up well
#: within this on a loaded 2-core machine.
START_TIMEOUT_S = 90.0
#: A clean stop of every hosted node, as test_shutdown bounds a single node's.
STOP_BOUND_S = 15.0
#: One small move: command to settled.
MOVE_TIMEOUT_S = 60.0
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def test_container_hosts_the_cell_moves_and_stops_on_sigterm(tmp_path: Path) -> None:
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as procs, \
            Client(domain, 'container_test') as client:
        poses = client.collect(PoseStamped, names.ESTIMATED_POSE, STREAM_QOS)
        container = procs.start(names.CONTAINER)
        hosted = {node.name for node in names.CELL_NODES}

        def all_up() -> bool:
            assert container.poll() is None, procs.log(names.CONTAINER)[-2000:]
            return hosted <= set(client.node.get_node_names()) and bool(poses)

        wait_until(all_up, START_TIMEOUT_S, f'nodes {sorted(hosted)} and {names.ESTIMATED_POSE}')
        # its own process group, in this test's session: not an autogroup of its own, whose
        # threads the kernel let go without CPU for 0.5-1.7 s beside the others' (processes.py)
        assert os.getpgid(container.pid) == container.pid
        assert os.getsid(container.pid) == os.getsid(0)
        for name, lax in LAX_LIVENESS.items():
            assert client.set_parameter(names.NODE_POSITIONER, f'liveness.{name}',
                                        float(lax)).successful, name
        homed, message = client.home()
        assert homed, message
        goal = MECH.home_position + np.array([0.002, -0.001, 0.0])
        assert client.plan(names.MOVE_TO_POSE, goal, IDENTITY, timeout=MOVE_TIMEOUT_S), \
            procs.log(names.CONTAINER)[-2000:]

        sent = time.monotonic()
        code = procs.stop(names.CONTAINER, sig=signal.SIGTERM, grace=STOP_BOUND_S)[
            names.CONTAINER]
        seconds = time.monotonic() - sent
        log = procs.log(names.CONTAINER)
        assert code == 0, log[-2000:]
        assert seconds < STOP_BOUND_S
        assert not [sign for sign in CRASH_SIGNS if sign in log], log[-2000:]


@pytest.mark.parametrize('nodes, why', [(['positioner', 'no_such_node'], 'no_such_node'),
                                        (['leg_driver', 'leg_driver'], 'named twice')])
def test_container_refuses_bad_node_names(nodes: list[str], why: str) -> None:
    with isolated_domain() as domain:
        done = subprocess.run([executable(names.CONTAINER), *nodes, '--ros-args'],
                              env=cell_environment(domain), capture_output=True, text=True,
                              timeout=60, check=False)
    assert done.returncode == 2
    assert why in done.stderr
