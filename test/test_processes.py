"""positioning_cell.ros.processes: the node that simulates the cell's drives
(names.SIMULATED_HARDWARE) starts with HARDWARE_NICE in every thread,
where this process may lower a nice value (root or CAP_SYS_NICE), so that command lines and
nodes starting beside a moving cell do not starve it, as they would not starve real drives;
the other nodes keep the nice value they inherit. Multi-process tier."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from cell_harness import Client, ProcessGroup, isolated_domain, wait_until

from positioning_cell import names
from positioning_cell.ros.processes import HARDWARE_EXECUTABLES, HARDWARE_NICE

pytestmark = pytest.mark.nodes

STARTUP = 60.0  # s; process start and discovery on a loaded 2-core VM (usually ~2 s)


def _may_lower_nice() -> bool:
    return subprocess.run([sys.executable, '-c', 'import os; os.nice(-1)'],
                          capture_output=True, check=False, timeout=30).returncode == 0


def _thread_nice(pid: int) -> set[int]:
    """The nice value of every thread of ``pid`` (/proc/<pid>/task/*/stat, field 19)."""
    values = set()
    for stat in Path(f'/proc/{pid}/task').glob('*/stat'):
        fields = stat.read_text().rsplit(')', 1)[1].split()
        values.add(int(fields[16]))  # field 19 counted from 1; fields[0] is field 3
    return values


def test_the_simulated_hardware_is_the_only_node_started_with_a_higher_priority(
        tmp_path: Path) -> None:
    assert {'leg_driver_node'} == HARDWARE_EXECUTABLES
    if not _may_lower_nice():
        pytest.skip('this process may not lower a nice value (no root, no CAP_SYS_NICE)')
    nodes = {names.CELL_NODES[0].executable: names.NODE_DRIVER,
             names.CELL_NODES[2].executable: names.NODE_POSITIONER}
    inherited = os.getpriority(os.PRIO_PROCESS, 0)
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain, 'priority_test') as client:
        procs = {exe: group.start(exe) for exe in nodes}
        wait_until(lambda: group.dead() or all(client.spinning(n) for n in nodes.values()),
                   STARTUP, 'the driver and the positioner spinning')
        assert not group.dead(), {k: group.log(k)[-1500:] for k in group.dead()}
        nice = {exe: _thread_nice(proc.pid) for exe, proc in procs.items()}
        codes = group.stop()
    assert codes == dict.fromkeys(nodes, 0), {k: group.log(k)[-1500:] for k in codes}
    assert nice['leg_driver_node'] == {HARDWARE_NICE}, nice  # DDS's threads too
    assert nice['kinematics_node'] == {inherited}, nice
