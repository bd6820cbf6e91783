"""The positioner's move state machine without DDS (positioning_cell.motion.mover): goal checks,
closed-loop correction, arrival, averaging, and whole moves against a fake world: settled,
corrected on a measured machine, refused, busy, stopped, timed out, faulted."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell import clearance as cl
from positioning_cell.core import kinematics
from positioning_cell.errors import InputError
from positioning_cell.motion.correction import corrected_command, deviation, mean_pose
from positioning_cell.motion.mover import (
    GoalTolerance,
    JointReading,
    Machine,
    MoveAbortedError,
    Mover,
    PositionerSettings,
    State,
    joints_arrived,
    validate_goal,
)
from positioning_cell.motion.trajectory import Trajectory
from positioning_cell.parameters import parse
from positioning_cell.tools.polling import wait_until

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize(('frame', 'p', 'q', 'words'), [
    ('tracker', [0, 0, 0.2], IDENTITY, "goal frame 'tracker' is not 'base'"),
    ('', [0, 0, 0.2], IDENTITY, "goal frame '' is not 'base'"),
    ('base', [0, np.nan, 0.2], IDENTITY, 'not finite'),
    ('base', [0, 0, 0.2], [0, 0, 0, 0], 'is zero'),
    ('base', [0, 0, 0.2], [0, 0, 0.1, 1], 'not 1'),
])
def test_goal_refusals(frame: str, p: list[float], q: np.ndarray, words: str) -> None:
    with pytest.raises(InputError, match=words):
        validate_goal(frame, p, q)


def test_goal_normalises_within_tolerance() -> None:
    _, q = validate_goal('base', [0, 0, 0.2], [0, 0, 0, 1 + 1e-7])
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)


def test_correction_converges_on_a_machine_with_clearance() -> None:
    """Measured correction (exact measurements) against the eq. 9 truth: the error shrinks
    by orders of magnitude per iteration (the clearance error varies slowly with the pose)."""
    rng = np.random.default_rng(0)
    truth = cl.EffectiveLengthClearance.random(1.6e-4, 1.6e-4, rng)
    p_des = MECH.home_position + [0.004, -0.003, 0.002]
    q_des = Rotation.from_rotvec([0.02, 0.01, -0.03]).as_quat()
    command = (p_des, q_des)
    errors = []
    for _ in range(4):
        joints = kinematics.inverse(MECH, *command)
        att = truth.attained_pose(MECH, joints.lengths, joints.thetas)
        e_p, _ = deviation(att.position[0], att.quaternion[0], p_des, q_des)
        errors.append(np.linalg.norm(e_p))
        command = corrected_command(*command, p_des, q_des, att.position[0], att.quaternion[0])
    assert errors[0] > 20e-6
    assert errors[1] < errors[0] / 20 and errors[3] < 1e-9


def test_tolerance_holds() -> None:
    tol = GoalTolerance(10e-6, 1e-4)
    assert tol.holds([6e-6, 0, 8e-6], [0, 0, 1e-4])
    assert not tol.holds([6e-6, 0, 8.1e-6], [0, 0, 0])
    assert not tol.holds([0, 0, 0], [0, 1.1e-4, 0])


def test_mean_pose() -> None:
    rng = np.random.default_rng(1)
    p = MECH.home_position + rng.normal(0, 1e-5, (50, 3))
    rot = Rotation.from_rotvec([0.1, 0, 0]) * Rotation.from_rotvec(rng.normal(0, 1e-4, (50, 3)))
    mp, mq = mean_pose(p, rot.as_quat())
    np.testing.assert_allclose(mp, p.mean(axis=0))
    err = (Rotation.from_quat(mq) * Rotation.from_rotvec([0.1, 0, 0]).inv()).magnitude()
    assert err < 1e-4 / np.sqrt(50) * 5


def test_joints_arrived() -> None:
    target = np.array([0.2, 0.2, 0.2, 0.0, 0.0, 0.0])
    tol_p, tol_v = [5e-6] * 3 + [5e-5] * 3, [1e-4] * 3 + [1e-3] * 3
    assert joints_arrived(target + 4e-6, np.zeros(6), target, tol_p, tol_v)
    assert not joints_arrived(target + [6e-6, 0, 0, 0, 0, 0], np.zeros(6), target, tol_p, tol_v)
    assert not joints_arrived(target, [0, 0, 0, 0, 2e-3, 0], target, tol_p, tol_v)


# -- whole moves against a fake world ----------------------------------------------------------
HOME_JOINTS = np.concatenate([kinematics.inverse(MECH, MECH.home_position,
                                                 MECH.home_quaternion).lengths[0],
                              kinematics.inverse(MECH, MECH.home_position,
                                                 MECH.home_quaternion).thetas[0]])
GOAL = MECH.home_position + np.array([0.003, -0.002, 0.001])
GOAL_Q = Rotation.from_rotvec([0.01, -0.02, 0.005]).as_quat()


class World:
    """The mover's outside world: drives that jump to the end of each trajectory (when
    ``follow``), encoders reading them, and a tracker measuring where a machine with clearance
    ``truth`` really puts the platform (``samples`` exact readings per look)."""

    def __init__(self, truth: cl.ClearanceModel = None, follow: bool = True,
                 samples: int = 10) -> None:
        self.position = HOME_JOINTS.copy()
        self.truth, self.follow, self.samples = truth, follow, samples
        self.trajectories: list[Trajectory] = []
        self.stops = 0
        self.targets: list[tuple[np.ndarray, np.ndarray]] = []
        self.states: list[tuple[State, str]] = []
        self.lock = threading.Lock()

    def machine(self) -> Machine:
        return Machine(send_trajectory=self.send, stop_drives=self.stop,
                       publish_target=lambda p, q: self.targets.append((p, q)),
                       latest_joints=self.latest, new_measurements=self.measurements,
                       state_changed=lambda s, r: self.states.append((s, r)))

    def send(self, traj: Trajectory) -> None:
        with self.lock:
            self.trajectories.append(traj)
            if self.follow:
                self.position = np.concatenate([traj.lengths[-1], traj.thetas[-1]])

    def stop(self) -> None:
        self.stops += 1

    def latest(self) -> JointReading:
        with self.lock:
            return JointReading(self.position.copy(), np.zeros(6))

    def attained(self) -> tuple[np.ndarray, np.ndarray]:
        with self.lock:
            q = self.position
        att = cl.attained_pose(MECH, self.truth, q[:3], q[3:])
        return att.position[0], att.quaternion[0]

    def measurements(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [self.attained()] * self.samples if self.samples else []

    def reasons(self) -> list[str]:
        return [r for _, r in self.states]


def settings(mode: str = 'none', **changes: object) -> PositionerSettings:
    """Positioner settings for fast tests: no dwell, short timeouts."""
    values = {'compensation.mode': mode, 'compensation.clearance.model': 'none',
              'settle_time': 0.0, 'arrival.timeout': 0.3, 'measurement_timeout': 0.3,
              **changes}
    return parse(PositionerSettings, values)


def mover(world: World, mode: str = 'none', **changes: object) -> Mover:
    m = Mover(settings(mode, **changes), world.machine())
    assert m.estimate_pose() is not None  # encoder readings are there
    return m


def test_a_move_settles_on_the_goal() -> None:
    world = World()
    m = mover(world)
    result = m.move('base', GOAL, GOAL_Q)
    assert m.state is State.SETTLED and result.reason == 'settled'
    assert len(world.trajectories) == 1 and len(world.targets) == 1
    np.testing.assert_allclose(world.targets[0][0], GOAL)
    ideal = kinematics.inverse(MECH, GOAL, GOAL_Q)
    np.testing.assert_allclose(world.position, np.concatenate([ideal.lengths[0],
                                                               ideal.thetas[0]]), atol=1e-12)
    np.testing.assert_allclose(result.positions[-1], GOAL, atol=1e-9)
    assert [s for s, _ in world.states][-3:] == [State.MOVING, State.SETTLING, State.SETTLED]


def test_measured_mode_corrects_a_machine_with_clearance_to_the_tolerance() -> None:
    truth = cl.EffectiveLengthClearance.random(1.6e-4, 1.6e-4, np.random.default_rng(3))
    world = World(truth)
    m = mover(world, 'measured')
    result = m.move('base', GOAL, GOAL_Q)
    assert result.reason.startswith('settled within tolerance'), result.reason
    assert len(world.trajectories) >= 2  # the first move, then corrections
    e_p, e_r = deviation(*world.attained(), GOAL, GOAL_Q)
    tol = m.settings.goal_tolerance
    assert np.linalg.norm(e_p) <= tol.position and np.linalg.norm(e_r) <= tol.orientation
    uncorrected = World(truth)
    mover(uncorrected).move('base', GOAL, GOAL_Q)
    assert np.linalg.norm(deviation(*uncorrected.attained(), GOAL, GOAL_Q)[0]) > 20e-6


@pytest.mark.parametrize(('frame', 'p', 'q', 'words'), [
    ('tracker', GOAL, GOAL_Q, "goal frame 'tracker' is not 'base'"),
    ('base', [0.0, np.nan, 0.196], GOAL_Q, 'not finite'),
    ('base', GOAL, [0.0, 0.0, 0.0, 0.0], 'is zero'),
    ('base', MECH.home_position + [0, 0, 0.03], GOAL_Q, 'leg 1 length'),
])
def test_refusals_say_why_and_move_nothing(frame: str, p: object, q: object, words: str) -> None:
    world = World()
    m = mover(world)
    for call in (m.check, m.move):
        with pytest.raises(MoveAbortedError, match=words):
            call(frame, p, q)
        assert m.state is State.ABORTED and words in m.reason
    assert not world.trajectories and not world.targets


def test_check_plans_without_moving() -> None:
    world = World()
    traj = mover(world).check('base', GOAL, GOAL_Q)
    np.testing.assert_allclose(traj.position[-1], GOAL, atol=1e-12)
    assert traj.limits.ok and not world.trajectories


def test_disabled_or_faulted_drives_refuse_motion() -> None:
    world = World()
    m = mover(world)
    m.driver_status({'enabled': 'false', 'state': 'disabled'})
    with pytest.raises(MoveAbortedError, match='drives disabled'):
        m.move('base', GOAL, GOAL_Q)
    m.driver_status({'enabled': 'true', 'state': 'fault', 'message': 'following error'})
    with pytest.raises(MoveAbortedError, match='drive fault: following error'):
        m.move('base', GOAL, GOAL_Q)
    assert not world.trajectories


def test_busy_then_stop_aborts_the_running_move() -> None:
    world = World(follow=False)  # the drives never arrive: the move waits
    m = mover(world, **{'arrival.timeout': 60.0})
    outcome: dict[str, object] = {}

    def first() -> None:
        try:
            m.move('base', GOAL, GOAL_Q)
        except MoveAbortedError as err:
            outcome['error'] = str(err)

    thread = threading.Thread(target=first)
    thread.start()
    wait_until(lambda: world.trajectories, 10.0, 'the first move to start')
    with pytest.raises(MoveAbortedError, match='busy'):
        m.move('base', MECH.home_position, MECH.home_quaternion)
    assert len(world.trajectories) == 1
    m.stop()
    thread.join(timeout=10.0)
    assert outcome['error'] == 'stopped by /positioner/stop' and world.stops == 1
    assert m.state is State.ABORTED


def test_drives_that_never_arrive_time_out() -> None:
    world = World(follow=False)
    m = mover(world)
    with pytest.raises(MoveAbortedError, match=r'timed out after .* waiting for the drives'):
        m.move('base', GOAL, GOAL_Q)


def test_a_fault_mid_move_aborts_and_the_next_move_starts_from_the_encoders() -> None:
    world = World(follow=False)
    m = mover(world, **{'arrival.timeout': 60.0})
    threading.Timer(0.2, m.driver_status, [{'state': 'fault', 'message': 'leg2 stuck'}]).start()
    with pytest.raises(MoveAbortedError, match='drive fault: leg2 stuck'):
        m.move('base', GOAL, GOAL_Q)
    m.driver_status({'state': 'holding', 'enabled': 'true'})
    world.follow = True
    m.move('base', GOAL, GOAL_Q)
    # The second trajectory starts where the encoders were (home), not at the aborted goal.
    np.testing.assert_allclose(world.trajectories[-1].position[0], MECH.home_position,
                               atol=1e-9)


def test_measured_mode_without_tracker_readings_times_out() -> None:
    world = World(samples=0)
    with pytest.raises(MoveAbortedError, match=r'waiting for 10 new samples on /metrology/pose'):
        mover(world, 'measured').move('base', GOAL, GOAL_Q)


def test_pose_estimate_and_a_fault_without_a_solution() -> None:
    world = World()
    m = Mover(settings(), world.machine())
    estimate = m.estimate_pose()
    assert estimate is not None and m.reason == 'ready'
    np.testing.assert_allclose(estimate.position, MECH.home_position, atol=1e-12)
    world.position = np.array([0.4, 0.2, 0.2, 0.0, 0.0, 0.0])  # legs that cannot close
    assert m.estimate_pose() is None and m.state is State.FAULT


def test_the_mode_can_change_between_moves() -> None:
    truth = cl.EffectiveLengthClearance.random(1.6e-4, 1.6e-4, np.random.default_rng(4))
    world = World(truth)
    m = mover(world)
    m.move('base', GOAL, GOAL_Q)
    assert len(world.trajectories) == 1
    m.reconfigure(settings('measured'))
    assert m.move('base', GOAL, GOAL_Q).reason.startswith('settled within tolerance')
