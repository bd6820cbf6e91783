"""``cell_container``: several of the cell's nodes in one process, ROS 2's composition pattern
without its component machinery (rclcpp_components has no rclpy counterpart).

    cell_container [NODE ...] --ros-args --params-file config/cell.yaml

NODE: node names (``leg_driver``, ``positioner``, ...; names.NODE_EXECUTABLES), built in the
order given; by default the cell's nodes (names.CELL_NODES). Each node is built by what runs it
alone (its module's ``main``, a NodeStart) and reads its own section of the parameter files, as
alone, and keeps its own executor. The nodes share one context and its DDS participant, the
interpreter and one copy of rclpy, numpy, scipy and numba: the memory composition saves
(:func:`positioning_cell.ros.spin.run_together`: the executors and why; docs/howto/run.md: the
figures). SIGINT and SIGTERM stop every node as they stop a node alone (the drives stop, a
recorder closes its bag), exit 0; a node that cannot be built ends them all, exit 2. A global
node rename (``-r __node:=x``) would rename every hosted node: rename one with
``-r <node>:__node:=x``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from rclpy.utilities import remove_ros_args

from positioning_cell import names
from positioning_cell.ros.entry import node_module
from positioning_cell.ros.spin import NodeStart, run_together

#: Node name -> its executable, for every node a container can host.
HOSTABLE = {node.name: node.executable for node in names.NODE_EXECUTABLES}


def hosted_nodes(argv: Sequence[str]) -> list[str]:
    """The node names the command line asks for (without its ROS arguments); the cell's nodes
    if it names none. Exits 2 (argparse) naming an unknown or repeated node."""
    parser = argparse.ArgumentParser(
        prog=names.CONTAINER, description="Several of the cell's nodes in one process.",
        epilog='ROS arguments follow --ros-args, as for a single node.')
    parser.add_argument('nodes', nargs='*', metavar='NODE',
                        help=f'node names, of {", ".join(HOSTABLE)} (default: '
                             f'{" ".join(n.name for n in names.CELL_NODES)})')
    chosen: list[str] = parser.parse_args(list(argv)).nodes
    unknown = [n for n in chosen if n not in HOSTABLE]
    if unknown:
        parser.error(f'unknown node(s) {", ".join(unknown)}: choose from {", ".join(HOSTABLE)}')
    repeated = sorted({n for n in chosen if chosen.count(n) > 1})
    if repeated:
        parser.error(f'node(s) named twice: {", ".join(repeated)}')
    return chosen or [n.name for n in names.CELL_NODES]


def node_start(name: str) -> NodeStart:
    """How node ``name`` starts: its module's ``main``."""
    start: NodeStart = importlib.import_module(node_module(HOSTABLE[name])).main
    return start


def main(args: list[str] | None = None) -> int:
    """Entry point of ``cell_container`` (``args``: the whole command line, as ``sys.argv``)."""
    argv = sys.argv if args is None else args
    starts = [node_start(name) for name in hosted_nodes(remove_ros_args(argv)[1:])]
    return run_together(starts, argv)
