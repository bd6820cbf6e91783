"""The tracker's registration as the positioner receives it: /metrology/registration, latched,
from the tracker node only (:class:`~positioning_cell.ros.latest.SourceReader`), converted to
the library's :class:`~positioning_cell.metrology.instrument.Registration`."""

from __future__ import annotations

import math
import time

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Registration
from positioning_cell.ros import messages as m
from positioning_cell.ros.latest import SourceReader
from positioning_cell.ros.qos import LATCHED_QOS

#: How often the registration is looked for, s (it changes only when the tracker re-locates).
LOOK_PERIOD = 0.5


class RegistrationReader:
    """The registration published by the node ``source`` (its fully qualified name)."""

    def __init__(self, node: Node, source: str) -> None:
        self._node = node
        self._reader = SourceReader(node, PoseWithCovarianceStamped, names.TRACKER_REGISTRATION,
                                    source, LATCHED_QOS)
        self._looked = -math.inf

    def take(self) -> Registration | None:
        """The registration published since the last call (None: nothing new, or not
        readable, which is logged: the caller keeps the one it has); looked for at most every
        :data:`LOOK_PERIOD` s. Nothing is taken before
        the graph names ``source`` as a publisher: the latched message arrives once, at
        discovery, and taken while its sender is still unnamed it would be dropped as a
        stranger's."""
        now = time.monotonic()
        if now - self._looked < LOOK_PERIOD:  # the mover asks at every poll; the graph
            return None                       # query behind publisher_count is not free
        self._looked = now
        if self._reader.publisher_count() == 0:
            return None
        msg = self._reader.newest()
        if msg is None:
            return None
        try:
            return m.registration(msg)
        except InputError as exc:
            self._node.get_logger().error(f'{names.TRACKER_REGISTRATION}: {exc}; not used')
            return None
