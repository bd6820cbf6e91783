"""A command line's ROS node started before its heavy imports: rclpy alone loads (~0.1 s),
the node's DDS participant is created and discovers the cell in Fast DDS's own threads while
the interpreter goes on importing numpy, scipy and the commands (~0.5 s); the client built on
it afterwards (:class:`positioning_cell.ros.client.CellClient` with ``node=``) finds the cell
already discovered and only its own endpoints to match. The environment is the cell's
processes' one first (:func:`positioning_cell.ros.processes.use_loopback`), and what the DDS
library writes to the process's standard output goes to stderr (:func:`answers_only_on_stdout`)."""

from __future__ import annotations

import os
import sys

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from positioning_cell.ros.entry import skip_code_generator
from positioning_cell.ros.processes import use_loopback

#: What :func:`start_node` gives, named for the command lines' type hints (they import no rclpy).
ClientNode = Node


def start_node(domain: int | None, prefix: str = 'cell') -> ClientNode:
    """A node named ``<prefix>_<pid>`` in a new context on ROS domain ``domain`` (None:
    ROS_DOMAIN_ID), this process on the loopback as the cell; rclpy's signal handlers left out
    (the command line handles SIGINT and SIGTERM). Whoever takes the node shuts its context
    down."""
    use_loopback()
    answers_only_on_stdout()
    skip_code_generator()
    context = Context()
    rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    return Node(f'{prefix}_{os.getpid()}', context=context)


def answers_only_on_stdout() -> None:
    """Keep the process's stdout for what the command line answers: file descriptor 1 (where
    C code writes: Fast DDS logs its errors to ``std::cout``, e.g. "RTPS_TRANSPORT_SHM Error
    ... open_and_lock_file failed" beside a participant that still holds its port) becomes a
    copy of stderr, and ``sys.stdout`` writes to the original stdout. Without it such a line
    came before a ``--json`` document on stdout, which then did not parse. Idempotent."""
    if getattr(sys.stdout, 'answers_only', False):
        return
    sys.stdout.flush()
    answers = os.dup(1)
    os.dup2(2, 1)
    stream = os.fdopen(answers, 'w', encoding=sys.stdout.encoding, errors=sys.stdout.errors,
                       buffering=1 if os.isatty(answers) else -1)
    stream.answers_only = True  # type: ignore[attr-defined]
    sys.stdout = stream


__all__ = ['ClientNode', 'answers_only_on_stdout', 'start_node']
