"""Which topics the recorder takes: the cell's topics (design/interfaces.md) by default, or a
list of names and/or a regular expression."""

from __future__ import annotations

import importlib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from positioning_cell.errors import InputError

#: Every topic of the cell's interface contract (design/interfaces.md), in its table order.
CELL_TOPICS = (
    '/legs/joint_trajectory',
    '/legs/joint_states',
    '/sim/legs/true_joint_states',
    '/positioner/target',
    '/positioner/pose',
    '/positioner/markers',
    '/metrology/pose',
    '/sim/platform/true_pose',
    '/accuracy/position_error',
    '/accuracy/orientation_error',
    '/diagnostics',
    '/cell/program',  # the run driver's current step (make run): mode, cycle, pose
)


@dataclass(frozen=True)
class TopicSelection:
    """Topics to record: those named in ``names`` plus those ``pattern`` fully matches."""

    names: frozenset[str]
    pattern: re.Pattern[str] | None = None

    @classmethod
    def from_params(cls, names: Sequence[str], pattern: str = '') -> TopicSelection:
        """From the recorder's ``topics`` list and ``topic_pattern`` regex; both empty means
        :data:`CELL_TOPICS`. Names must be absolute; InputError for a bad name or regex."""
        bad = [n for n in names if not n.startswith('/') or n.endswith('/') or ' ' in n]
        if bad:
            raise InputError(f'topics: {bad!r} are not absolute topic names ("/ns/name")')
        try:
            regex = re.compile(pattern) if pattern else None
        except re.error as err:
            raise InputError(f'topic_pattern = {pattern!r} is not a regular expression: {err}') \
                from err
        if not names and regex is None:
            return cls(frozenset(CELL_TOPICS))
        return cls(frozenset(names), regex)

    def matches(self, topic: str) -> bool:
        """True when ``topic`` is to be recorded."""
        return topic in self.names or (
            self.pattern is not None and self.pattern.fullmatch(topic) is not None)


def message_class(msgtype: str) -> Any:
    """The Python class of ROS message type ``pkg/msg/Type`` from its generated package (what
    an rclpy publisher or subscription needs); InputError if it is not installed."""
    parts = msgtype.split('/')
    if len(parts) != 3 or parts[1] != 'msg' or not all(parts):
        raise InputError(f'{msgtype!r} is not a ROS message type name (pkg/msg/Type)')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[2])
    except (ImportError, AttributeError) as err:
        raise InputError(f'message type {msgtype} is not installed: {err}') from err
