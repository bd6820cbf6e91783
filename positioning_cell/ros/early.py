"""A command line's ROS node started before its heavy imports: rclpy alone loads (~0.1 s),
the node's DDS participant is created and discovers the cell in Fast DDS's own threads while
the interpreter goes on importing numpy, scipy and the commands (~0.5 s); the client built on
it afterwards (:class:`positioning_cell.ros.client.CellClient` with ``node=``) finds the cell
already discovered and only its own endpoints to match. The environment is the cell's
processes' one first (:func:`positioning_cell.ros.processes.use_loopback`)."""

from __future__ import annotations

import os

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from positioning_cell.ros.processes import use_loopback

#: What :func:`start_node` gives, named for the command lines' type hints (they import no rclpy).
ClientNode = Node


def start_node(domain: int | None, prefix: str = 'cell') -> ClientNode:
    """A node named ``<prefix>_<pid>`` in a new context on ROS domain ``domain`` (None:
    ROS_DOMAIN_ID), this process on the loopback as the cell; rclpy's signal handlers left out
    (the command line handles SIGINT and SIGTERM). Whoever takes the node shuts its context
    down."""
    use_loopback()
    context = Context()
    rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    return Node(f'{prefix}_{os.getpid()}', context=context)


__all__ = ['ClientNode', 'start_node']
