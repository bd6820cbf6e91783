"""The live_view node in the test process, watched through its Foxglove WebSocket server by a
real client (foxglove_ws: ``websockets`` with the ``foxglove.sdk.v1`` subprotocol): the four
channels and their schemas are advertised; the scene, transforms and deviation it sends match
a command and a measurement the test published; it follows the accuracy monitor's tolerance
when that is changed; it publishes nothing to the cell. The deviation mathematics itself:
test_watch.py."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from cell_harness import InProcess, wait_until
from fake_cell import FakeCell
from foxglove_ws import FoxgloveClient, Received
from rclpy.node import Node
from scipy.spatial.transform import Rotation

from positioning_cell import names
from positioning_cell.accuracy.monitor import TOLERANCES_PREFIX
from positioning_cell.errors import ConfigError
from positioning_cell.nodes.accuracy_monitor_node import AccuracyMonitorNode
from positioning_cell.nodes.live_view_node import LiveViewNode
from positioning_cell.sim.pose_measurement import TARGETS_PREFIX

pytestmark = pytest.mark.nodes

HOME_P = np.array([0.0, 0.0, 0.19596])
HOME_Q = np.array([0.0, 0.0, 0.0, 1.0])
OFFSET = np.array([30e-6, -20e-6, 10e-6])  # measured − commanded, m: |Δp| 37.4 µm
TURN_DEG = 0.002  # measured rotated about base z by this much
SIGMA = 5e-6  # m, the tracker's stated position σ per axis
CHANNELS = [names.LIVE_SCENE, names.LIVE_TRANSFORMS, names.LIVE_DEVIATION, names.LIVE_STATUS]
TARGETS = [0.1, 0.0, 0.02, -0.05, 0.08, 0.02, -0.05, -0.08, 0.02, 0.0, 0.0, 0.1]


class Publisher(FakeCell):
    """The test playing the cell: home commanded, the pose measured off by OFFSET and TURN_DEG."""

    def __init__(self, ros: InProcess) -> None:
        super().__init__(ros.client.node)
        self.measured_p = HOME_P + OFFSET
        self.measured_q = Rotation.from_euler('z', TURN_DEG, degrees=True).as_quat()

    def tick(self) -> Any:
        """One estimate and one measurement; the measurement's stamp."""
        self.estimated(HOME_P, HOME_Q)
        return self.measure(self.measured_p, self.measured_q, SIGMA, 1e-5)


def _until(ws: FoxgloveClient, cell: Publisher, topic: str, accept: Any,
           timeout: float = 20.0) -> Received:
    """Publish a tick every 50 ms until a message on ``topic`` satisfies ``accept``."""
    deadline = time.monotonic() + timeout
    while (time_left := deadline - time.monotonic()) > 0:
        cell.tick()
        got = ws.receive(min(0.05, time_left))
        while got is not None:
            if got.topic == topic and accept(got.message):
                return got
            got = ws.receive(0.0)
    raise TimeoutError(f'no accepted {topic} within {timeout} s')


@pytest.fixture
def live(ros: InProcess) -> Any:
    return ros.start(LiveViewNode, port=0)


def test_channels_are_advertised_with_their_schemas(live: Any) -> None:
    assert live.server.port > 0 and live.url.startswith('ws://127.0.0.1:')
    with FoxgloveClient(live.url) as ws:
        ws.wait_channels(CHANNELS, 20.0)
        ch = ws.channels
    assert ch[names.LIVE_SCENE]['schemaName'] == 'foxglove.SceneUpdate'
    assert ch[names.LIVE_SCENE]['encoding'] == 'protobuf'
    assert ch[names.LIVE_TRANSFORMS]['schemaName'] == 'foxglove.FrameTransforms'
    for topic in (names.LIVE_DEVIATION, names.LIVE_STATUS):
        assert ch[topic]['encoding'] == 'json' and ch[topic]['schemaEncoding'] == 'jsonschema'
    assert 'x_um' in ch[names.LIVE_DEVIATION]['schema']
    assert ch[names.LIVE_DEVIATION]['schemaName'] == 'positioning_cell.LiveDeviation'


def test_deviation_scene_and_transforms_match_the_published_poses(ros: InProcess,
                                                                   live: Any) -> None:
    cell = Publisher(ros)
    cell.command(HOME_P, HOME_Q)
    with FoxgloveClient(live.url) as ws:
        ws.wait_channels(CHANNELS, 20.0)
        ws.subscribe(CHANNELS)
        dev = _until(ws, cell, names.LIVE_DEVIATION, lambda d: True).message
        entities: dict[str, Any] = {}  # an entity stays drawn until replaced: the union

        def drawn(update: dict[str, Any]) -> bool:
            entities.update({e['id']: e for e in update['entities']})
            return {'base', 'legs', 'platform', 'commanded', 'error'} <= set(entities) and \
                bool(entities['error'].get('arrows'))

        _until(ws, cell, names.LIVE_SCENE, drawn)
        tfs = _until(ws, cell, names.LIVE_TRANSFORMS, lambda t: len(t['transforms']) >= 3)
    # the deviation: the offset the test put in, in µm and degrees, and its tolerance verdict
    assert [dev['x_um'], dev['y_um'], dev['z_um']] == pytest.approx(OFFSET * 1e6, abs=1e-6)
    assert dev['rz_deg'] == pytest.approx(TURN_DEG, abs=1e-9)
    assert dev['rx_deg'] == pytest.approx(0.0, abs=1e-9)
    assert dev['position_error_um'] == pytest.approx(np.linalg.norm(OFFSET) * 1e6, abs=1e-6)
    assert dev['position_tolerance_um'] == pytest.approx(50.0)  # the defaults: no monitor
    assert dev['in_tolerance'] is True and all(dev['axis_in_tolerance'])
    # U (k = 2) of |Δp| with σ 5 µm per axis: about 2σ; 37.4 + U within 50 µm: conforms
    assert dev['position_uncertainty_um'] == pytest.approx(2 * SIGMA * 1e6, rel=0.1)
    assert dev['decision'] == 'conforms' and dev['decision_rule'] == 'iso_14253_1'
    assert dev['uncertainty'][:3] == pytest.approx([SIGMA] * 3, rel=1e-9)
    # the scene: base, legs, platform, the commanded ghost, and the magnified error arrow
    arrow = entities['error']['arrows'][0]
    length = arrow['shaft_length'] + arrow['head_length']
    assert length == pytest.approx(1000.0 * np.linalg.norm(OFFSET), rel=1e-6)
    tail = arrow['pose']['position']
    assert [tail['x'], tail['y'], tail['z']] == pytest.approx(HOME_P.tolist(), abs=1e-12)
    sphere = entities['error']['spheres'][0]
    assert sphere['size']['x'] == pytest.approx(2 * 1000.0 * 50e-6)
    assert len(entities['legs']['lines'][0]['points']) == 6
    # the frame transforms: the measured platform where it was measured
    by_child = {t['child_frame_id']: t for t in tfs.message['transforms']}
    measured = by_child[names.PLATFORM_MEASURED_FRAME]['translation']
    assert [measured[k] for k in 'xyz'] == pytest.approx(cell.measured_p, abs=1e-12)
    assert by_child[names.PLATFORM_COMMANDED_FRAME]['parent_frame_id'] == names.BASE_FRAME


def test_it_follows_the_monitor_tolerance_and_the_user_frame(ros: InProcess) -> None:
    ros.start(AccuracyMonitorNode)
    layout = Node(names.NODE_MEASUREMENT, context=ros.context)  # the tracker's target layout
    layout.declare_parameter(f'{TARGETS_PREFIX}platform', TARGETS)
    ros.executor.add_node(layout)
    ros.nodes.append(layout)
    live = ros.start(LiveViewNode, port=0, frame='user')
    cell = Publisher(ros)
    cell.command(HOME_P, HOME_Q)
    wait_until(lambda: live.state.snapshot().tolerances is not None, 30.0,
               "the monitor's tolerances")
    with FoxgloveClient(live.url) as ws:
        ws.wait_channels(CHANNELS, 20.0)
        ws.subscribe(CHANNELS)
        scene = _until(ws, cell, names.LIVE_SCENE, lambda s: any(
            e['id'] == 'targets' for e in s['entities'])).message
        assert len(next(e for e in scene['entities'] if e['id'] == 'targets')['spheres']) == 4
        # 30 µm tolerance: |Δp| 37.4 µm is out, and so is x (30 µm equals it: in)
        result = ros.client.set_parameter(names.NODE_MONITOR, f'{TOLERANCES_PREFIX}position',
                                           30e-6)
        assert result.successful, result.reason
        dev = _until(ws, cell, names.LIVE_DEVIATION,
                     lambda d: d['position_tolerance_um'] == pytest.approx(30.0)).message
        assert dev['in_tolerance'] is False
        assert dev['axis_in_tolerance'][:3] == [True, True, True]
        assert dev['decision'] == 'indeterminate'  # 37.4 µm lies within U of 30 µm
        # the user frame: turned 90° about z, 10 mm along x; the object 50 mm up
        cell.coordinate_systems(([0.01, 0.0, 0.0],
                                 Rotation.from_euler('z', 90, degrees=True).as_quat()),
                                ([0.0, 0.0, 0.05], HOME_Q))
        dev = _until(ws, cell, names.LIVE_DEVIATION, lambda d: d['frame'] == 'user' and abs(
            d['x_um'] - OFFSET[1] * 1e6) < 1.0).message
    # along user x (= base y) the offset's y, along user y (= −base x) minus its x; the pivot
    # 50 mm up turns with the 0.002° about z, which moves it along no axis (it is on z)
    assert dev['x_um'] == pytest.approx(OFFSET[1] * 1e6, abs=1e-6)
    assert dev['y_um'] == pytest.approx(-OFFSET[0] * 1e6, abs=1e-6)
    assert dev['rz_deg'] == pytest.approx(TURN_DEG, abs=1e-9)


def test_the_live_view_commands_nothing(live: Any) -> None:
    topics = {pub.topic_name for pub in live.publishers}
    assert topics <= {names.DIAGNOSTICS, '/rosout', names.PARAMETER_EVENTS}, topics
    assert {c.srv_name for c in live.clients} <= {
        f'/{names.NODE_MONITOR}/get_parameters', f'/{names.NODE_MEASUREMENT}/get_parameters'}


def test_a_taken_port_is_refused_with_the_reason(ros: InProcess, live: Any) -> None:
    port = live.server.port
    with pytest.raises(ConfigError, match=f'cannot serve on 127.0.0.1:{port}.*in use'):
        ros.start(LiveViewNode, port=port)
