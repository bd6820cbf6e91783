"""A node process's ROS context and DDS participant, made before its heavy imports.

rmw_fastrtps creates a context's participant with the context's first node, and the cell's
other participants need some 0.2 s to discover a new one (announcements, then the exchange of
endpoints) before any of them can reach its services. Made by the node itself, after its
imports (numpy, the library, its messages: 0.25-0.35 s) and its construction, that discovery
came last: a bare rclpy node that imported the recorder's modules before its participant
answered in 0.46-0.70 s (median 0.61), and 0.40-0.45 s (median 0.42) when a first node had
made the participant before those imports (ad hoc, 8 starts each, alternated; the bare node
0.29). :func:`start` initialises the default context from the command line and makes its
participant with a hidden node (no services, no /rosout; only the /parameter_events
publisher every rclpy node has), from the entry point (:mod:`positioning_cell.ros.entry`)
right after rclpy is imported; Fast DDS discovers the
cell in its own threads while the interpreter imports the node's modules.
:func:`positioning_cell.ros.spin.run_together` takes that context as it finds it and ends
the hidden node (:func:`end`) only as the process ends, with its own nodes. Ended as soon as
they were built, their endpoints announced and the hidden node's publisher withdrawn at once,
a running client sometimes discovered those endpoints ~0.9 s late: the monitor's parameter
service ready to it after 1.16-1.21 s instead of 0.25-0.45 s in 2 of 14 and 2 of 10 starts,
the node built and spinning at 0.25 s (ad hoc, stage marks in the node). That is Fast DDS's
endpoint discovery repaired at its next heartbeat, once a second (``edp_heartbeat_period``,
not configurable in the XML profile). With the hidden node kept: none in 24 starts, nor
without the early participant (24 starts, 0.36-0.62 s).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.type_description_service import START_TYPE_DESCRIPTION_SERVICE_PARAM
from rclpy.utilities import get_default_context

_starters: list[Node] = []


def start(args: Sequence[str] | None = None) -> None:
    """Initialise the default context with ``args`` (None: ``sys.argv``; its ``--ros-args``,
    as the node's own ``rclpy.init`` would) without rclpy's signal handlers, and make its
    participant: a node named ``_start_<pid>`` (hidden from ``ros2 node list``) that takes no
    remapping or parameter from the command line and has no parameter services, /rosout or
    type description service (only the /parameter_events publisher rclpy gives every
    node)."""
    rclpy.init(args=list(args) if args is not None else None,
               signal_handler_options=SignalHandlerOptions.NO)
    _starters.append(Node(
        f'_start_{os.getpid()}', use_global_arguments=False, start_parameter_services=False,
        enable_rosout=False,
        parameter_overrides=[Parameter(START_TYPE_DESCRIPTION_SERVICE_PARAM, value=False)]))


def started() -> bool:
    """Whether this process's default context is initialised and not shut down (by
    :func:`start` or an earlier ``rclpy.init``)."""
    return get_default_context().ok()


def end() -> None:
    """Destroy the node :func:`start` made (if any), as the process ends (module docstring);
    the participant stays while the context has another node."""
    while _starters:
        _starters.pop().destroy_node()


__all__ = ['end', 'start', 'started']
