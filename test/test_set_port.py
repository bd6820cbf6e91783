"""A set's drives that stop a move on their own (issue 27): the rule the positioner and the
coordinator share (:func:`~positioning_cell.moves.drive_stops.drives_stopped`), and the
coordinator's port of a set ending the move as soon as it hears the drives, before the set's
positioner (starved of the CPU in a shipped run) reports it. The port on a fake client: no
DDS, the drives' status handed to its subscription."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock

from positioning_cell import names
from positioning_cell.coordinated.coordinator import PanelRequest
from positioning_cell.moves.drive_stops import drives_stopped
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.moves.timing import Timing
from positioning_cell.ros.set_port import RosSetPort

pytestmark = pytest.mark.nodes  # imports rclpy (the port's client), starts no node

READY = {'state': 'idle', 'enabled': 'true', 'silence_stops': '2', 'message': 'ready'}


def test_the_drives_stopped_a_move_when_in_fault_off_or_counting_a_silence_stop() -> None:
    assert drives_stopped(READY, '2') is None
    assert drives_stopped(READY) is None
    code, reason = drives_stopped({**READY, 'state': 'fault', 'message': 'following error'},
                                  '2') or (None, '')
    assert code is ResultCode.ABORTED_FAULT and reason == 'drive fault: following error'
    code, reason = drives_stopped({**READY, 'enabled': 'false'}, '2') or (None, '')
    assert code is ResultCode.ABORTED_DRIVES_OFF and reason.startswith('drives disabled')
    stopped = {**READY, 'silence_stops': '3', 'last_event': 'commander silent for 1.60 s'}
    code, reason = drives_stopped(stopped, '2') or (None, '')
    assert code is ResultCode.ABORTED_DRIVER_LOST and reason.endswith('(commander silent for '
                                                                      '1.60 s)')
    assert drives_stopped(stopped) is None  # no move sent: no count to compare with


class _Future:
    """A MoveToPose call the set has not answered."""

    def done(self) -> bool:
        return False


class _Node:
    def __init__(self) -> None:
        self.subscriptions: dict[str, Callable[[Any], None]] = {}

    def create_subscription(self, _type: Any, topic: str, callback: Callable[[Any], None],
                            _qos: Any) -> None:
        self.subscriptions[topic] = callback

    def get_clock(self) -> Clock:
        return Clock()


class _Client:
    """What RosSetPort uses of a CellClient: its node, and services whose calls hang."""

    def __init__(self) -> None:
        self.node = _Node()
        self.sent: list[Any] = []

    def service(self, _type: Any, name: str, _wait: float) -> Any:
        client = self

        class Service:
            def call_async(self, request: Any) -> _Future:
                client.sent.append((name, request))
                return _Future()
        return Service()


def _drives(port_client: _Client, ns: str, values: dict[str, str]) -> None:
    """The set's leg driver's status on its /diagnostics (beside another node's)."""
    msg = DiagnosticArray(status=[
        DiagnosticStatus(name=names.STATUS_POSITIONER, message='moving',
                         values=[KeyValue(key='state', value='fault')]),
        DiagnosticStatus(name=names.STATUS_DRIVER, message=values.get('message', ''),
                         values=[KeyValue(key=k, value=v) for k, v in values.items()
                                 if k != 'message'])])
    port_client.node.subscriptions[names.in_set(names.DIAGNOSTICS, ns)](msg)


def _move(port: RosSetPort) -> Callable[[], Any]:
    goal = (np.array([0.0, 0.0, 0.19]), np.array([0.0, 0.0, 0.0, 1.0]))
    return port.move(goal, PanelRequest(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
                     Timing(1.0, 200.0), np.zeros(3))


def test_drives_that_stop_for_a_silent_positioner_end_its_move_for_the_coordinator() -> None:
    client = _Client()
    port = RosSetPort(client, 'p2', 1.0)  # type: ignore[arg-type]
    _drives(client, 'p2', READY)
    poll = _move(port)
    assert client.sent and client.sent[0][0] == names.in_set(names.MOVE_TO_POSE, 'p2')
    assert poll() is None  # running: the set has not answered, its drives follow
    _drives(client, 'p2', {**READY, 'state': 'stopping', 'message': 'moving'})
    assert poll() is None
    _drives(client, 'p2', {**READY, 'silence_stops': '3',
                           'last_event': 'commander /p2/positioner silent for 1.60 s'})
    ended = poll()
    assert ended is not None and ended.code is ResultCode.ABORTED_DRIVER_LOST
    assert ended.reason.startswith('its drives stopped on their own: the drives stopped the '
                                   'move') and ended.attained is None


def test_a_count_first_heard_after_the_move_was_sent_is_its_baseline() -> None:
    """Statuses not heard yet when the move is sent (the port just made): the first one after
    sets the count; only a later stop, a fault or drives off end the move."""
    client = _Client()
    port = RosSetPort(client, 'p1', 1.0)  # type: ignore[arg-type]
    poll = _move(port)
    assert poll() is None
    _drives(client, 'p1', {**READY, 'silence_stops': '7'})
    assert poll() is None
    _drives(client, 'p1', {**READY, 'silence_stops': '7', 'state': 'fault',
                           'message': 'following error on leg2_length'})
    ended = poll()
    assert ended is not None and ended.code is ResultCode.ABORTED_FAULT
    assert ended.reason.endswith('drive fault: following error on leg2_length')
