"""The coordinated cell on ROS (issue 27, items 1 and 3): two positioners, each its node set
under its own namespace, and the cell_coordinator moving the panel with both as one. What
the drives are sent (each set's /<ns>/legs/joint_trajectory) shows one time base; what the
simulators' true axes did shows the two machines starting together; a refusal, a stop of one
positioner and a cancel are seen to stop both."""

from __future__ import annotations

import json
import shlex
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from action_msgs.msg import GoalStatus
from cell_harness import (
    CELL_YAML,
    FAST_MOTION,
    LOADED_COMMAND,
    LOADED_LIVENESS,
    Client,
    InProcess,
    ProcessGroup,
    executable,
    isolated_domain,
    stop_cleanly,
)
from diagnostic_msgs.msg import DiagnosticArray
from foxglove_ws import FoxgloveClient
from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Path as PathMsg
from positioning_cell_interfaces.action import MoveToPose
from positioning_cell_interfaces.msg import MoveCommand, MoveOutcome
from rclpy.qos import QoSProfile
from rich.console import Console
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from tmux_pane import TmuxPane
from trajectory_msgs.msg import JointTrajectory

from positioning_cell import names
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.panel_motion import pair_disagreement
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.mechanics.statics import Payload, actuator_efforts
from positioning_cell.motion.settings import COMPENSATION_MODE
from positioning_cell.nodes.live_view_node import LiveViewNode
from positioning_cell.nodes.live_view_panel import PANEL_STATUS_SCHEMA, base_frame
from positioning_cell.polling import wait_until
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.ros.client import GoalClient
from positioning_cell.ros.messages import (
    path_arrays,
    pose_arrays,
    pose_stamped,
    seconds,
    status_values,
    wrench_of,
)
from positioning_cell.ros.node_sets import start_coordinated
from positioning_cell.ros.panel_watch_inputs import PanelWatchSource
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, STREAM_QOS
from positioning_cell.tools.cell_watch_panel import render_panel
from positioning_cell.watch.panel import PanelSnapshot
from positioning_cell.watch.state import is_stale

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

SETS = ('p1', 'p2')
#: Two positioners 1.2 m apart, each clamping the panel 50 mm above its platform (two balls
#: would not hold it: it would turn about the line through them).
CELL_FILE = {'cell': {'positioners': [
    {'name': name, 'base': [1.2 * k, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
     'attachment': {'kind': 'clamp', 'offset': [0.0, 0.0, 0.05]}}
    for k, name in enumerate(SETS)]}}
#: The sets as tests of coordination want them: machines as their model says (no geometric
#: error, clearance, drive or thermal error, compliance, tracker bias: what the positioners
#: disagree by is what a test injects, seen through the trackers' noise), the nominal model
#: (the moves end on the encoders), fast motion, liveness for a loaded machine.
OVERRIDES = {
    # Two cells of a module run side by side beside the other workers: a set's container was
    # seen silent for 1.02 s while homing, and for 1.5 s mid-move (a stall looks like a frozen
    # encoder too). Liveness is test_faults'.
    names.NODE_POSITIONER: {'compensation': {'mode': 'none'}, 'motion': FAST_MOTION,
                            'liveness': {**LOADED_LIVENESS, 'joint_silence': 3.0,
                                         'tracker_silence': 3.0, 'freeze_window': 3.0}},
    # A start 2 s ahead: on a loaded machine (three workers beside the docs build) a set took
    # over the default 0.5 s to plan its move, and refused a start already past.
    names.NODE_DRIVER: {'command': {**LOADED_COMMAND, 'max_start_delay': 3.0}},
    # and a stop's common instant 0.2 s ahead (each set answers its StopAlongPath within it;
    # one that does not stops at once)
    names.NODE_COORDINATOR: {'timing': {'start_lead': 2.0, 'stop_lead': 0.2}},
    names.NODE_MEASUREMENT: {'truth': {
        'geometry_seed': -1, 'clearance': {'model': 'none'}, 'drives': {'enabled': False},
        'thermal': {'enabled': False}, 'compliance': {'enabled': False},
        'tracker': {'scale_ppm': 0.0, 'angle_offsets': [0.0, 0.0]}}},
    # the cell installed as its file says (an uncalibrated cell's bases put millimetres of
    # misfit, kilonewtons, into the panel)
    names.NODE_PANEL_SIMULATOR: {'installation': {
        'base_position_sigma': 0.0, 'base_angle_sigma': 0.0, 'socket_sigma': 0.0}},
}
#: p2's model wrong by 0.2 mm (issue 27's fault): its U-joint centres 0.2 mm off along x, so
#: its platform really stands 0.2 mm off along −x, toward p1, wherever it is sent.
P2_WRONG = {'p2': {names.NODE_POSITIONER: {'mechanism': {
    'base_offsets': [2e-4, 0.0, 0.0] * 3}}}}
IDENTITY = [0.0, 0.0, 0.0, 1.0]


class CoordinatedCell:
    """The running cell: the test's client, each set's drive commands, the panel action's
    client, and the streams a test asks for (:meth:`stream`: subscribed at its first call, so
    that this process takes only what its tests read, ~100 messages/s each)."""

    def __init__(self, client: Client, procs: ProcessGroup) -> None:
        self.client, self.procs = client, procs
        self.sent = {ns: client.collect(JointTrajectory, names.in_set(names.JOINT_TRAJECTORY, ns),
                                        QoSProfile(depth=100))
                     for ns in SETS}
        self._streams: dict[str, list[Any]] = {}
        self.goals = GoalClient(client, MoveToPose, names.COORDINATED_MOVE_ACTION)
        self.up = False  # the panel 4 mm up (_moved_together)
        self.domain = -1  # its ROS domain

    def stream(self, msg_type: Any, topic: str) -> list[Any]:
        """The messages on ``topic`` since its first call (an absolute name)."""
        if topic not in self._streams:
            self._streams[topic] = self.client.collect(msg_type, topic, STREAM_QOS)
        return self._streams[topic]

    def truth(self, ns: str) -> list[JointState]:
        """Set ``ns``'s true axes."""
        return self.stream(JointState, names.in_set(names.TRUE_JOINT_STATES, ns))

    def move(self, position: list[float], quaternion: list[float] = IDENTITY,
             speed_scale: float = 0.0, during: Any = None, timeout: float = 60.0
             ) -> tuple[int, MoveOutcome, list[Any]]:
        """Move the panel (cell frame); ``during(handle, feedback)`` runs once the move is
        under way. The goal's status, its outcome and the feedback seen."""
        command = MoveCommand(mode=MoveCommand.ABSOLUTE, speed_scale=speed_scale)
        command.pose = pose_stamped(position, quaternion, self.client.node.get_clock().now()
                                    .to_msg(), names.CELL_FRAME)
        feedback: list[Any] = []
        sent = len(self.sent['p1'])
        handle = self.goals.send(MoveToPose.Goal(command=command), feedback.append)
        assert handle.accepted
        result = handle.get_result_async()
        if during is not None:  # once p1's drives have started (the action's feedback may
            # not have matched yet: the move is judged by what the drives were sent)
            def under_way() -> bool:
                return result.done() or (len(self.sent['p1']) > sent and seconds(
                    self.sent['p1'][-1].header.stamp) < time.time() - 0.1)
            self.goals.until(under_way, 30.0, 'the panel move under way')
            assert not result.done(), result.result().result.outcome.reason
            during(handle, feedback)
        self.goals.until(result.done, timeout, 'the result of the panel move')
        response = result.result()
        return response.status, response.result.outcome, feedback


def _running(tmp: Path, per_set: Any = None) -> Iterator[CoordinatedCell]:
    """Two node sets and the coordinator, both positioners homed."""
    path = tmp / 'two_positioners.yaml'
    path.write_text(yaml.safe_dump(CELL_FILE))
    with isolated_domain() as domain, ProcessGroup(domain, tmp) as procs, \
            Client(domain, 'coordinated_test') as client:
        start_coordinated(procs, cell_file.load(path), [CELL_YAML], tmp / 'params', OVERRIDES,
                          per_set)
        cell = CoordinatedCell(client, procs)
        cell.domain = domain
        try:
            for ns in SETS:
                done, message = client.home(namespace=ns)
                assert done, f'{ns}: {message}'
                # found now, so that a stop during a move is not held up by its discovery
                client.service(Trigger, names.in_set(names.STOP, ns))
            cell.goals.ready(60.0)
            yield cell
        finally:
            cell.goals.close()
        stop_cleanly(procs)


@pytest.fixture(scope='module')
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CoordinatedCell]:
    """The two positioners agree (within their trackers' noise)."""
    yield from _running(tmp_path_factory.mktemp('coordinated'))


@pytest.fixture(scope='module')
def faulty_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CoordinatedCell]:
    """p2's model wrong by 0.2 mm."""
    yield from _running(tmp_path_factory.mktemp('faulty'), P2_WRONG)


@pytest.fixture
def faulty_cell_timed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CoordinatedCell]:
    """p2's model wrong by 0.2 mm, for the timing tier (not relaxed by another test). Stopped
    after its one test: kept for the module, its idle cell ran beside the timed tests of
    ``cell`` and made their drives start tens of ms apart (on 2 cores)."""
    yield from _running(tmp_path_factory.mktemp('faulty_timed'), P2_WRONG)


@pytest.mark.timing
def test_the_internal_force_abort_stops_both_within_half_a_second(
        faulty_cell_timed: CoordinatedCell) -> None:
    """Issue 27's target: the abort ≤ 0.5 s after the force is exceeded (the reading that
    showed it). Timed: alone, after the parallel tier; first of the module's timed tests, so
    that no other cell runs beside this one."""
    stops, exceeded = _stopped_by_force(faulty_cell_timed)
    assert all(stops[ns] - exceeded <= 0.5 for ns in SETS), (stops, exceeded)


def _crossings(states: list[JointState], since: float, shares: list[float]) -> list[float]:
    """When (s, interpolated between readings) the true axis that travels furthest since
    ``since`` crossed each share of its travel. Both machines' servos are the same linear
    system following one time law: they cross a share at the same time after their start, so
    the difference of two machines' crossings is the difference of their starts."""
    states = list(states)  # one snapshot: a collecting subscription appends to it as we read
    stamps = np.array([seconds(s.header.stamp) for s in states])
    positions = np.array([s.position for s in states])
    keep = stamps >= since
    stamps, positions = stamps[keep], positions[keep]
    travel = positions[-1] - positions[0]
    axis = int(np.argmax(np.abs(travel[:3])))  # the legs (m): the thetas are in rad
    share = (positions[:, axis] - positions[0, axis]) / travel[axis]
    out = []
    for target in shares:
        k = int(np.flatnonzero(share >= target)[0])
        w = (target - share[k - 1]) / (share[k] - share[k - 1])
        out.append(float(stamps[k - 1] + w * (stamps[k] - stamps[k - 1])))
    return out


def _moved_together(cell: CoordinatedCell) -> tuple[JointTrajectory, list[float]]:
    """A panel move 4 mm up (or back down, after one up): p1's trajectory as sent, and when
    each set's true legs crossed half their travel (:func:`_crossings`), after both drives
    were seen to get one start and one duration."""
    before = {ns: len(cell.sent[ns]) for ns in SETS}
    since = cell.client.node.get_clock().now().nanoseconds * 1e-9
    for ns in SETS:
        cell.truth(ns)
    cell.up = not cell.up
    status, outcome, _ = cell.move([0.0, 0.0, 0.004 if cell.up else 0.0], speed_scale=0.5)
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert 'every positioner settled' in outcome.reason and 'internal force at most' in \
        outcome.reason
    new = {ns: cell.sent[ns][before[ns]:] for ns in SETS}
    assert all(len(new[ns]) == 1 for ns in SETS), {ns: len(new[ns]) for ns in SETS}
    first, second = (new[ns][0] for ns in SETS)
    assert seconds(first.header.stamp) > 0.0  # a start, not "on receipt"
    assert first.header.stamp == second.header.stamp
    assert first.points[-1].time_from_start == second.points[-1].time_from_start
    # The panel's attained pose (the positioners' estimates) at the goal; its cell frame.
    assert outcome.attained.header.frame_id == names.CELL_FRAME
    assert np.linalg.norm(outcome.position_error) < 20e-6
    start, end = seconds(first.header.stamp), seconds(first.points[-1].time_from_start)
    wait_until(lambda: all(cell.truth(ns) and seconds(cell.truth(ns)[-1].header.stamp)
                           > start + end + 1.0 for ns in SETS), 20.0, 'the axes at rest')
    return first, [_crossings(cell.truth(ns), since, [0.5])[0] for ns in SETS]


def test_a_panel_move_sends_both_drives_one_start_and_one_duration(
        cell: CoordinatedCell) -> None:
    """The machines move after the commanded start (sent 2 s ahead: on receipt they would
    have moved before it) and before its end; each positioner publishes its plan, a pose
    per trajectory point stamped at its commanded instant (what the force watch judges
    against)."""
    plans = cell.stream(PathMsg, names.in_set(names.PLANNED_PATH, 'p1'))
    first, crossings = _moved_together(cell)
    start, end = seconds(first.header.stamp), seconds(first.points[-1].time_from_start)
    assert all(start < c < start + end for c in crossings), (crossings, start)
    plan = wait_until(lambda: next((p for p in reversed(plans) if seconds(p.header.stamp)
                                    == pytest.approx(start)), None), 10.0, "p1's plan")
    stamps, positions, _ = path_arrays(plan)
    offsets = [seconds(point.time_from_start) for point in first.points]
    np.testing.assert_allclose(stamps - start, offsets, rtol=0, atol=1e-6)  # float s at 1.8e9
    assert plan.header.frame_id == names.BASE_FRAME and positions.shape == (len(offsets), 3)


@pytest.mark.timing
def test_the_two_machines_cross_mid_travel_within_half_a_drive_period(
        cell: CoordinatedCell) -> None:
    """The two machines move as one: their true legs cross half their travel within 5 ms of
    each other (half a period of the drives' 100 Hz physics: each starts its trajectory at its
    stamp's instant within a tick, not at the tick). Half way the legs move at
    their peak speed, so a late reading does not bend the interpolation (in the ramps, a
    50 ms gap did: a skew that was not). Timed: alone, after the parallel tier."""
    _, (one, two) = _moved_together(cell)
    print(f'mid-travel crossings: skew {abs(one - two) * 1e3:.3f} ms')
    assert abs(one - two) <= 0.005, (one, two)


#: A turn of the panel about its origin (at p1's base): p2, 1.2 m away, travels ~8 mm.
TURN = [0.0, 0.0045, 0.005]


@pytest.mark.timing
def test_a_turning_panel_move_keeps_the_attachments_together(cell: CoordinatedCell) -> None:
    """Issue 27's target, judged by the panel simulator's truth (each pair's stretch, the
    sets' true poses taken at one instant): during a panel move that turns it 6.7 mrad and
    back, the attachments keep within 20 µm of the rigid panel's distance. Each platform
    moves about the panel's origin (the coordinator's pivots): on its own straight line, p2
    would leave its arc by ~7 µm (test_coordinator: the chord), and the drives' following
    errors part them too. Timed (alone, after the parallel tier): it judges motion the
    simulated drives' Python timers make: with the timed faulty cell idle beside it (module
    scope) the force watch stopped the turn at 503 N in the CI of 0f38395, and the truth
    read 42 µm once, the drives starting tens of ms apart; it is now stopped after its test
    (7 runs of the timed tests alone since: 0.7-4.1 µm)."""
    forces = cell.stream(String, names.PANEL_FORCES)
    wait_until(lambda: bool(forces), 30.0, 'the panel simulator\'s forces')
    height = [0.0, 0.0, 0.004 if cell.up else 0.0]
    worst = []
    for rotvec in (TURN, [0.0, 0.0, 0.0]):
        since = time.time()
        status, outcome, _ = cell.move(height, list(Rotation.from_rotvec(rotvec).as_quat()))
        assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
        assert status == GoalStatus.STATUS_SUCCEEDED
        until = time.time()
        wait_until(lambda until=until: json.loads(forces[-1].data)['stamp'] > until, 10.0,
                   'the truth after the move')
        during = [r for r in (json.loads(m.data) for m in list(forces))
                  if since <= r['stamp'] <= until]
        assert len(during) > 10, len(during)
        worst.append(max(r['largest_stretch_um'] for r in during))
    print(f'largest stretch during the turn and back: {worst[0]:.1f}, {worst[1]:.1f} um')
    assert max(worst) <= 20.0, worst


@pytest.mark.timing
def test_a_panel_stopped_at_speed_comes_to_rest_with_the_attachments_together(
        cell: CoordinatedCell) -> None:
    """The coordinator's stop of a panel move at speed (15 mm/s along the line of the
    attachments, where two platforms that do not stop as one pull them apart): both drives
    are sent the stop along the path, one start and one duration, and judged by the panel
    simulator's truth the attachments keep within 20 µm of the rigid panel's distance until
    the panel rests (stopped at once, each drive when the stop reached it: 58-66 µm here, and
    902 N in the shipped cell's panel). Timed, as the turning move: the truth of the simulated
    drives' timers."""
    forces = cell.stream(String, names.PANEL_FORCES)
    wait_until(lambda: bool(forces), 30.0, "the panel simulator's forces")
    before = {ns: len(cell.sent[ns]) for ns in SETS}

    def stop_at_speed(_handle: Any, feedback: list[Any]) -> None:
        cell.goals.until(lambda: bool(feedback) and feedback[-1].progress >= 0.4, 30.0,
                         'the panel at speed')
        done, message = cell.client.trigger(names.COORDINATED_STOP)
        assert done, message

    since = time.time()
    height = 0.004 if cell.up else 0.0
    status, outcome, _ = cell.move([0.012, 0.0, height], speed_scale=0.5, during=stop_at_speed)
    assert outcome.code == MoveOutcome.ABORTED_STOP, outcome.reason
    assert status == GoalStatus.STATUS_ABORTED
    until = time.time() + 0.5
    stops = {}
    for ns in SETS:
        new = cell.sent[ns][before[ns]:]
        assert len(new) >= 2 and new[1].points, [len(t.points) for t in new]
        stops[ns] = new[1]
        assert not any(stops[ns].points[-1].velocities)  # at rest at its end
    assert stops['p1'].header.stamp == stops['p2'].header.stamp
    assert stops['p1'].points[-1].time_from_start == stops['p2'].points[-1].time_from_start
    wait_until(lambda: json.loads(forces[-1].data)['stamp'] > until, 10.0,
               'the truth after the stop')
    during = [r for r in (json.loads(m.data) for m in list(forces)) if since <= r['stamp']
              <= until]
    worst = max(r['largest_stretch_um'] for r in during)
    print(f'largest stretch while stopping from speed: {worst:.1f} um')
    assert worst <= 20.0, worst


def test_a_goal_one_positioner_cannot_reach_is_refused_naming_it_and_nothing_moves(
        cell: CoordinatedCell) -> None:
    before = {ns: len(cell.sent[ns]) for ns in SETS}
    # Turned 0.5 rad about the panel's z: p2, 1.2 m from the origin, would move 0.58 m.
    status, outcome, _ = cell.move([0.0, 0.0, 0.0], [0.0, 0.0, 0.247404, 0.968912])
    assert outcome.code == MoveOutcome.REFUSED_LIMITS, outcome.reason
    assert status == GoalStatus.STATUS_ABORTED
    assert outcome.reason.startswith('refused, nothing moved: ') and 'p2: ' in outcome.reason
    assert {ns: len(cell.sent[ns]) for ns in SETS} == before


def test_a_stop_of_one_positioner_stops_the_other_and_names_it(cell: CoordinatedCell) -> None:
    before = {ns: len(cell.sent[ns]) for ns in SETS}

    def stop_p2(_handle: Any, _feedback: list[Any]) -> None:
        done, message = cell.client.trigger(names.in_set(names.STOP, 'p2'))
        assert done, message

    status, outcome, feedback = cell.move([0.0, 0.0, 0.012], speed_scale=0.1, during=stop_p2)
    assert outcome.code == MoveOutcome.ABORTED_STOP, outcome.reason
    assert status == GoalStatus.STATUS_ABORTED
    # The feedback (matched since the first move): the share of the common motion elapsed.
    shares = [f.progress for f in feedback]
    assert shares and all(0.0 <= x < 1.0 for x in shares) and shares == sorted(shares)
    assert outcome.reason.startswith('p2: ') and 'every positioner stopped' in outcome.reason
    # p1 was sent its move and then the stop (an empty trajectory).
    sent = wait_until(lambda: (new if len(new := cell.sent['p1'][before['p1']:]) >= 2
                               and not new[-1].points else None), 10.0, "p1's stop")
    assert sent[0].points


def test_a_cancel_stops_both(cell: CoordinatedCell) -> None:
    before = {ns: len(cell.sent[ns]) for ns in SETS}

    def cancel(handle: Any, _feedback: list[Any]) -> None:
        cell.goals.cancel(handle)

    # far from where the stop before left the panel: a move of a few um would be over first
    status, outcome, _ = cell.move([0.0, 0.0, 0.012], speed_scale=0.1, during=cancel)
    assert outcome.code == MoveOutcome.ABORTED_STOP, outcome.reason
    assert status == GoalStatus.STATUS_CANCELED
    for ns in SETS:  # each ended with the stop
        wait_until(lambda ns=ns: (new := cell.sent[ns][before[ns]:]) and not new[-1].points,
                   10.0, f"{ns}'s stop")


def test_the_node_sets_keep_to_their_namespaces(cell: CoordinatedCell) -> None:
    """Every topic of a set is under its namespace: no node of a set publishes or subscribes
    on a root name (the coordinator's own /diagnostics is the root's)."""
    node = cell.client.node
    topics = {t for t, _ in node.get_topic_names_and_types()}
    for ns in SETS:
        assert {names.in_set(t, ns) for t in (names.JOINT_TRAJECTORY, names.JOINT_STATES,
                                               names.MEASURED_POSE, names.TF)} <= topics
    stray = sorted(
        (t, f'{i.node_namespace}/{i.node_name}') for t in topics & set(names.SET_TOPICS)
        for i in [*node.get_publishers_info_by_topic(t), *node.get_subscriptions_info_by_topic(t)]
        if i.node_namespace.strip('/') in SETS)
    assert stray == [], stray


def test_the_panel_watch_shows_the_running_cell(cell: CoordinatedCell) -> None:
    """``cell watch --panel``'s inputs on the running cell (issue 27 item 6): the coordinator's
    status and cell file, the panel's tracker, both sets' positioner and drives, and an
    internal force from their load cells; drawn naming both. Its subscriptions go with it."""
    subscribed = len(list(cell.client.node.subscriptions))
    source = PanelWatchSource(cell.client.node)
    try:
        def complete() -> PanelSnapshot | None:
            s = source.snapshot()
            ready = (s.coordinator is not None and s.names == SETS and s.panel is not None
                     and set(s.positioners) == set(s.drives) == set(SETS)
                     and not isinstance(s.internal_force(), str))
            return s if ready else None

        snapshot = wait_until(complete, 30.0, 'every input of the panel watch')
    finally:
        source.close()
    force = snapshot.internal_force()
    assert isinstance(force, float) and 0.0 <= force < 1e4, force
    assert snapshot.coordinator is not None
    assert snapshot.coordinator.values['positioners'] == ' '.join(SETS)
    console = Console(record=True, width=160, color_system=None)
    console.print(render_panel(snapshot, time.time()))
    text = console.export_text()
    assert all(f' {ns} ' in text for ns in SETS) and 'N at most at one attachment' in text
    assert len(list(cell.client.node.subscriptions)) == subscribed  # none of its own left


@pytest.mark.skipif(shutil.which('tmux') is None, reason='needs tmux')
def test_cell_watch_panel_draws_the_running_cell_and_q_quits(cell: CoordinatedCell,
                                                             tmp_path: Path) -> None:
    """``cell watch --panel`` in a terminal (a tmux pane): the coordinator, the panel, the
    internal force and both positioners' rows; q quits, exit 0."""
    command = f'{shlex.quote(executable("cell"))} watch --panel --domain {cell.domain}'
    with TmuxPane(f'pc_panel_{cell.domain}', command, cell_environment(cell.domain),
                  tmp_path) as pane:
        def drawn() -> str | None:
            screen = pane.screen()
            rows = [line for line in screen.splitlines() if line.strip()[:4] in ('│ p1', '│ p2')]
            known = len(rows) == 2 and not any('│ ?' in row for row in rows)  # states, drives
            # the coordinator's level is the module's last panel move's (a stop: WARN)
            return screen if known and 'N at most at one attachment' in screen \
                and 'mrad' in screen and 'coordinator: ' in screen else None

        try:
            screen = wait_until(drawn, 90.0, 'the panel watch window')
        except TimeoutError as err:
            raise AssertionError(f'{err}; the pane shows:\n{pane.screen()}') from err
        assert 'cell watch: the panel' in screen
        pane.keys('q')
        wait_until(lambda: 'exited' in pane.screen(), 30.0, 'the watch to quit on q')
        assert 'exited 0' in pane.screen()


def test_the_live_view_shows_the_panel_its_forces_and_every_positioner(
        cell: CoordinatedCell) -> None:
    """``live_view`` with ``view: panel`` on the running cell (issue 27 item 6), watched by a
    Foxglove client: its status channel gives the coordinator, both positioners and an
    internal force from their load cells; its scene draws both bases, both positioners' legs
    and platforms, the panel and a force arrow at each ball; its transforms put the panel and
    both bases in the cell frame."""
    ros = InProcess(cell.domain)
    try:
        live = ros.start(LiveViewNode, view='panel', port=0)
        channels = [names.LIVE_SCENE, names.LIVE_TRANSFORMS, names.LIVE_STATUS]
        seen: dict[str, Any] = {'entities': {}}
        with FoxgloveClient(live.url) as ws:
            ws.wait_channels(channels, 30.0)
            assert ws.channels[names.LIVE_STATUS]['schemaName'] == PANEL_STATUS_SCHEMA
            ws.subscribe(channels)

            def complete() -> bool:
                got = ws.receive(0.1)
                while got is not None:
                    if got.topic == names.LIVE_SCENE:
                        seen['entities'].update({e['id']: e for e in got.message['entities']})
                    else:
                        seen[got.topic] = got.message
                    got = ws.receive(0.0)
                status = seen.get(names.LIVE_STATUS)
                # the scene and the status are published apart: wait for a status that
                # has heard the panel measured too, not only a scene that draws it
                return status is not None and status['internal_force_n'] is not None \
                    and status['coordinator'] is not None \
                    and status['panel_age_s'] is not None \
                    and all(p['positioner'] is not None for p in status['positioners']) \
                    and {'bases', 'positioners', 'panel', 'forces'} <= set(seen['entities'])

            try:
                wait_until(complete, 60.0, 'the panel view complete')
            except TimeoutError as err:
                raise AssertionError(f"{err}: scene {sorted(seen['entities'])}, status "
                                     f'{seen.get(names.LIVE_STATUS)}') from err
    finally:
        ros.close()
    status = seen[names.LIVE_STATUS]
    assert status['coordinator'] is not None
    # measured (its age, not its staleness: on a loaded machine a reading may come late)
    assert status['panel_age_s'] is not None and status['panel_stale'] is is_stale(
        status['panel_age_s'])
    assert [p['name'] for p in status['positioners']] == list(SETS)
    assert [a['name'] for a in status['attachments']] == list(SETS)
    assert 0.0 <= status['internal_force_n'] < 1e4
    assert len(seen['entities']['forces']['arrows']) == len(SETS)
    assert len(seen['entities']['bases']['lines']) == len(SETS)
    assert len(seen['entities']['positioners']['lines']) == 1 + len(SETS)  # legs, platforms
    frames = {t['child_frame_id'] for t in seen[names.LIVE_TRANSFORMS]['transforms']}
    assert frames == {names.PANEL_FRAME, *(base_frame(ns) for ns in SETS)}


def test_a_set_is_reached_through_a_port_of_its_own(cell: CoordinatedCell) -> None:
    """The procedures' port on one set (RosCellPort(namespace=...), as run_cell --cell
    calibrates each positioner): its homing, encoders, tracker and parameters, not another
    set's nor a single cell's."""
    port = RosCellPort(cell.client, 30.0, namespace='p2')
    assert port.home().success
    assert port.mode() == 'none' and port.calibration_file() == ''
    readings = port.readings(3, 30.0)
    assert readings.position.shape == (3, 3) and readings.encoder.shape == (6,)
    # p2's platform, as its own tracker sees it in its base: at home
    assert np.linalg.norm(readings.position.mean(axis=0)
                          - Mechanism.default().home_position) < 1e-3
    taken, _ = port._set(COMPENSATION_MODE, 'not_a_mode')
    assert not taken  # p2's positioner refused it: the parameter went to /p2/positioner
    with pytest.raises(ProcedureError, match='/p9/metrology/pose'):  # no such set
        RosCellPort(cell.client, 30.0, namespace='p9').readings(1, 0.2)


def _stopped_by_force(cell: CoordinatedCell) -> tuple[dict[str, float], float]:
    """Issue 27's fault: p2's model wrong by 0.2 mm. Its tracker sees its platform 0.2 mm
    off where its trajectory commands it; the 1e7 N/m clamps make that over 1000 N between p1
    and p2 (the limit: 500 N). When each positioner's drives began to stop (stopped along the
    path: the stop's start, its trajectory's stamp; at once: the stamp of its ``aborted`` state
    on its /diagnostics, its own clock, not when this busy test process heard of it), and the
    stamp of the reading that showed the excess (the coordinator's status)."""
    diagnostics = {ns: cell.client.collect(DiagnosticArray,
                                           names.in_set(names.DIAGNOSTICS, ns), DIAGNOSTICS_QOS)
                   for ns in SETS}
    statuses = cell.client.statuses(names.STATUS_COORDINATOR)
    before = {ns: len(cell.sent[ns]) for ns in SETS}
    status, outcome, _ = cell.move([0.0, 0.0, 0.008], speed_scale=0.5)
    assert outcome.code == MoveOutcome.ABORTED_INTERNAL_FORCE, outcome.reason
    assert status == GoalStatus.STATUS_ABORTED
    assert 'between p1 and p2 above the limit 500 N' in outcome.reason
    assert 'every positioner stopped' in outcome.reason
    values = wait_until(lambda: next((v for v in map(status_values, statuses)
                                      if 'internal_force_exceeded_at' in v), None),
                        10.0, "the coordinator's status")
    exceeded, seen = (float(values[k]) for k in ('internal_force_exceeded_at',
                                                 'internal_force_seen_at'))

    def stopped(ns: str) -> float | None:
        along = [t for t in cell.sent[ns][before[ns] + 1:] if t.points]
        if along:
            return seconds(along[0].header.stamp)
        return next((seconds(array.header.stamp) for array in diagnostics[ns]
                     for s in array.status if s.name == names.STATUS_POSITIONER
                     and status_values(s).get('state') == 'aborted'
                     and seconds(array.header.stamp) > exceeded - 1.0), None)

    def both() -> dict[str, float] | None:
        found = {ns: stopped(ns) for ns in SETS}
        return {ns: t for ns, t in found.items() if t is not None} if all(
            t is not None for t in found.values()) else None

    try:
        stops: dict[str, float] = wait_until(both, 10.0, 'both positioners aborted')
    except TimeoutError as err:  # what each set was sent and said, for the next reader
        def seen(ns: str) -> str:
            sent = [(len(t.points), round(seconds(t.header.stamp) - exceeded, 3))
                    for t in cell.sent[ns][before[ns]:]]
            states = [status_values(s).get('state') for array in diagnostics[ns]
                      for s in array.status if s.name == names.STATUS_POSITIONER]
            return f'{ns}: sent (points, stamp - exceeded) {sent}, states {states[-5:]}'
        raise AssertionError(f'{err}: ' + '; '.join(map(seen, SETS))) from err
    print(f'exceeded {exceeded:.3f}: seen +{seen - exceeded:.3f} s, stopped +'
          + ', '.join(f'{ns} {stops[ns] - exceeded:.3f} s' for ns in SETS))
    return stops, exceeded


def test_a_panel_move_that_loads_the_panel_beyond_its_limit_stops_both_naming_the_pair(
        faulty_cell: CoordinatedCell) -> None:
    stops, exceeded = _stopped_by_force(faulty_cell)
    assert all(stops[ns] > exceeded for ns in SETS), (stops, exceeded)





def _at_rest(cell: CoordinatedCell) -> dict[str, Any]:
    """After 0.3 s more of the cell at rest: the true (p1, p2) stretch (m), the panel
    simulator's largest pair force (N), p2's push and its true pose, and p2's legs' load
    cells (N: the three axial forces)."""
    since = time.time() + 0.3
    mech = Mechanism.default()
    two = cell_file.load(cell.procs.log_dir / 'two_positioners.yaml')

    true_poses = {ns: cell.stream(PoseStamped, names.in_set(names.TRUE_POSE, ns))
                  for ns in SETS}
    # the panel simulator's truth, and what p2's legs' load cells read
    push = cell.stream(WrenchStamped, names.in_set(names.PANEL_WRENCH, 'p2'))
    forces = cell.stream(String, names.PANEL_FORCES)
    load_cells = cell.stream(JointState, names.in_set(names.JOINT_STATES, 'p2'))

    def after(msgs: list[Any]) -> bool:
        return bool(msgs) and seconds(msgs[-1].header.stamp) > since

    wait_until(lambda: all(after(true_poses[ns]) for ns in SETS) and after(push)
               and after(load_cells) and bool(forces)
               and json.loads(forces[-1].data)['stamp'] > since, 30.0, 'the cell at rest')
    poses = [pose_arrays(true_poses[ns][-1].pose) for ns in SETS]
    (pair,) = pair_disagreement(two, mech, poses)
    return {'stretch': pair.stretch,
            'force': max(p['force_n'] for p in json.loads(forces[-1].data)['pairs']),
            'push': wrench_of(push[-1]), 'pose': poses[1],
            'legs': np.array(load_cells[-1].effort[:3])}


def test_relax_puts_the_panel_at_rest_and_the_next_move_goes_through(
        faulty_cell: CoordinatedCell) -> None:
    """Judged by the simulators' truth: p2's 0.2 mm pulls the attachments 0.2 mm together and
    loads the panel (the panel simulator's forces, which p2's load cells read as the statics
    of its push say); relax moves both onto the rigid placement their trackers imply, the
    force goes, and the next panel move, carrying the corrections, is no longer stopped."""
    cell = faulty_cell
    before = _at_rest(cell)
    assert before['stretch'] == pytest.approx(-2e-4, abs=2e-5)  # the fault, toward p1
    assert before['force'] > 500.0
    done, message = cell.client.trigger(names.COORDINATED_RELAX)
    assert done and message.startswith('success: relaxed: moved p1 '), message
    relaxed = _at_rest(cell)
    # Within the readings' noise: 10 readings of each tracker leave ~10 um, ~100 N at 1e7 N/m
    # (seen: 13 um, 108 N against 1041 N before).
    assert abs(relaxed['stretch']) < 2e-5 and relaxed['force'] < 0.25 * before['force']
    # The load cells: what changed in p2's axial forces is the statics of what changed in
    # the panel's push on it (mechanics.statics, from the true pose).
    mech = Mechanism.default()
    gravity = [0.0, 0.0, -9.80665]

    def legs(state: dict[str, Any]) -> np.ndarray:
        push = tuple(float(v) for v in state['push'])
        payload = Payload(mass=0.0, gravity=(0.0, 0.0, gravity[2]), external_wrench=push)
        return actuator_efforts(mech, *state['pose'], payload)[0, :3]

    changed = before['legs'] - relaxed['legs']
    assert np.abs(changed).max() > 100.0
    np.testing.assert_allclose(changed, legs(before) - legs(relaxed), atol=1.0)
    status, outcome, _ = cell.move([0.0, 0.0, 0.004], speed_scale=0.5)
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert abs(_at_rest(cell)['stretch']) < 2e-5
