"""The cell_coordinator node in the test process, without its node sets: a close cuts short
the load-cell reading a settled panel move leaves running in the background (the strain map's
rest sample), so that the node stops within its deadline even when the sets are gone. The
coordinated cell on ROS: test_coordinated_cell."""

from __future__ import annotations

import threading
import time

import pytest
from cell_harness import InProcess

from positioning_cell.nodes.cell_coordinator_node import CellCoordinatorNode
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import STOPPED_WAIT_S

pytestmark = pytest.mark.nodes


def test_a_close_cuts_short_a_load_cell_reading_of_absent_sets(ros: InProcess) -> None:
    """The shipped cell's sets absent: the reading would wait the coordinator's answer
    timeout (10 s in config/cell.yaml, the stop deadline's length) for a first joint state;
    the close ends it within the client's stopped wait."""
    node = ros.start(CellCoordinatorNode)
    assert node.params.settings.answer_timeout >= 10.0
    coordinator = node.coordinator
    client = node._client
    assert client is not None
    subscribed = len(list(client.node.subscriptions))
    reading = threading.Thread(target=coordinator._sample_rest, daemon=True)
    reading.start()
    # under way: the first set's joint states subscribed for the reading (never answered)
    wait_until(lambda: len(list(client.node.subscriptions)) > subscribed, 10.0,
               'the reading to subscribe to the first set')
    assert reading.is_alive()
    closed = time.monotonic()
    node.close()
    reading.join(timeout=30.0)
    assert not reading.is_alive()
    assert time.monotonic() - closed < STOPPED_WAIT_S + 2.0
    assert coordinator.strain is not None and len(coordinator.strain) == 0
