"""A stop along the path (moves.stopping, issue 27): the running move's time law slowed to rest,
every setpoint on its path; several positioners stopped so from one instant keep the rigid
panel, where the drives' own stops strain it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.coordinator import Coordinator
from positioning_cell.coordinated.panel_motion import platform_goals
from positioning_cell.core.kinematics import forward
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import interpolated_pose
from positioning_cell.errors import InputError
from positioning_cell.moves.stopping import SHORTEST, joined_late, stop_along_path
from positioning_cell.moves.trajectory import Trajectory, plan_move
from positioning_cell.sim.panel import PanelTruth
from positioning_cell.sim.paths import JointPath, stop_path
from positioning_cell.sim.servo import ServoSettings

MECH = Mechanism.default()
CELL = cell_file.load(config_path('three_positioners.yaml'))
HOME = (MECH.home_position, MECH.home_quaternion)


def _joints(traj: Trajectory) -> JointPath:
    return JointPath(traj.times, np.hstack([traj.lengths, traj.thetas]),
                     np.hstack([traj.length_rates, traj.theta_rates]))


@settings(max_examples=25, deadline=None)
@given(fraction=st.floats(0.05, 0.95), duration=st.floats(0.05, 1.0),
       move=st.lists(st.floats(-0.004, 0.004), min_size=3, max_size=3),
       turn=st.lists(st.floats(-0.01, 0.01), min_size=3, max_size=3))
def test_a_stop_along_the_path_joins_the_move_and_stays_on_its_path(
        fraction: float, duration: float, move: list[float], turn: list[float]) -> None:
    """From any instant of a move and over any duration: the stop starts where the drives
    stand on the move (position and velocity, as they interpolate it), ends at rest, and every
    point is the move's own at the path time the linearly falling rate reaches (integrated
    here by the trapezoid rule, exact for a linear rate); its rates are its positions'
    derivative (finite differences)."""
    goal = (MECH.home_position + np.asarray(move), Rotation.from_rotvec(turn).as_quat())
    traj = plan_move(MECH, *HOME, *goal, period=0.01)
    elapsed = fraction * traj.duration
    stop = stop_along_path(traj, elapsed, duration)
    assert stop.times[0] == 0.0 and stop.times[-1] == pytest.approx(duration, rel=1e-12)
    original, stopped = _joints(traj), _joints(stop)
    q0, v0 = original.sample([elapsed])
    q, v = stopped.sample(stop.times)
    np.testing.assert_allclose(q[0], q0[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(v[0], v0[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(v[-1], 0.0, atol=0)
    rate = 1.0 - stop.times / duration
    tau = elapsed + np.concatenate([[0.0], np.cumsum(np.diff(stop.times)
                                                     * (rate[1:] + rate[:-1]) / 2.0)])
    tau = np.minimum(tau, traj.duration)
    np.testing.assert_allclose(q, original.sample(tau)[0], rtol=0, atol=1e-12)
    for k in range(0, stop.times.size, 7):
        p, quat = interpolated_pose(traj.times, traj.position, traj.quaternion, tau[k])
        np.testing.assert_allclose(stop.position[k], p, rtol=0, atol=1e-12)
        assert abs(abs(float(np.dot(stop.quaternion[k], quat))) - 1.0) < 1e-12
    # the rates are the derivative of the positions the drives interpolate
    fine = np.linspace(0.0, duration, 2001)[1:-1]
    h = 1e-6
    ahead, behind = stopped.sample(fine + h)[0], stopped.sample(fine - h)[0]
    scale = max(float(np.abs(v0).max()), 1e-6)
    np.testing.assert_allclose((ahead - behind) / (2 * h), stopped.sample(fine)[1], rtol=0,
                               atol=1e-4 * scale)


def test_a_stop_past_the_goal_ends_at_the_goal_and_bad_durations_are_refused() -> None:
    traj = plan_move(MECH, *HOME, MECH.home_position + [0.002, 0.0, 0.0], HOME[1], period=0.01)
    stop = stop_along_path(traj, traj.duration - 0.05, 1.0)
    np.testing.assert_allclose(stop.lengths[-1], traj.lengths[-1], atol=0)
    np.testing.assert_allclose(stop.length_rates[-10:], 0.0, atol=0)
    for bad in (0.0, -1.0, float('nan'), float('inf')):
        with pytest.raises(InputError, match='positive number of seconds'):
            stop_along_path(traj, 0.1, bad)
    with pytest.raises(InputError, match='elapsed'):
        stop_along_path(traj, float('nan'), 0.2)


def test_a_positioner_that_hears_the_stop_late_rests_at_the_same_point_of_its_path() -> None:
    """δ late, from then over T − 2δ: at rest where the stop on time rests (the same joints,
    to their last bits' scale); T/2 late or more, stopped at once; early, unchanged."""
    traj = plan_move(MECH, *HOME, MECH.home_position + [0.004, -0.002, 0.003],
                     Rotation.from_rotvec([0.003, 0.0, -0.004]).as_quat(), period=0.01)
    elapsed, duration = 0.4 * traj.duration, 0.3
    on_time = _joints(stop_along_path(traj, elapsed, duration)).final
    for late in (0.01, 0.05, 0.12):
        joined = joined_late(100.0, duration, 100.0 + late)
        assert joined is not None
        start, remaining = joined
        assert start == pytest.approx(100.0 + late) and remaining == pytest.approx(
            duration - 2 * late)
        stop = _joints(stop_along_path(traj, elapsed + late, remaining))
        np.testing.assert_allclose(stop.final, on_time, rtol=0, atol=1e-12)
    assert joined_late(100.0, duration, 100.0 + duration / 2 - SHORTEST / 4) is None
    assert joined_late(100.0, duration, 99.0) == (100.0, duration)


def test_positioners_stopped_along_their_paths_at_once_keep_the_panel_unstrained() -> None:
    """The shipped three-positioner cell turning and moving its panel on one time law (as the
    coordinator sends it), stopped mid-move: stopped along their paths from one instant over one
    duration, the platforms (their joints through the forward kinematics) keep the rigid panel,
    judged by the panel simulator's internal forces (1e7 N/m); each drive stopping on its own
    (its controlled stop from the same setpoint) strains it with hundreds of newtons."""
    goal_p, goal_q = np.array([0.004, -0.003, 0.003]), Rotation.from_rotvec(
        [0.004, -0.003, 0.005]).as_quat()
    goals = platform_goals(CELL, MECH, goal_p, goal_q)
    pivots = _pivots()
    plans = [plan_move(MECH, *HOME, *goal, period=0.01, duration=3.0, pivot=pivot)
             for goal, pivot in zip(goals, pivots, strict=True)]
    truth = PanelTruth(CELL, MECH)
    elapsed, duration = 1.4, 0.4  # mid-move, at speed
    a_max = ServoSettings().acceleration_limits

    def worst_force(paths: list[JointPath], times: np.ndarray) -> float:
        worst = 0.0
        joints = [path.sample(times)[0] for path in paths]
        poses = [forward(MECH, q[:, :3], q[:, 3:]) for q in joints]
        for k in range(times.size):
            state = truth.state([(pose.position[k], pose.quaternion[k]) for pose in poses])
            worst = max(worst, state.pairs[0][1])
        return worst

    times = np.linspace(0.0, duration + 0.2, 61)
    along = worst_force([_joints(stop_along_path(plan, elapsed, duration)) for plan in plans],
                        times)

    def own_stops(lags: list[float]) -> float:
        """Each drive's controlled stop from its setpoint when the stop reaches it, ``lags``
        s after the first (the drives' own stop is at once: it cannot wait for an instant)."""
        own = []
        for plan, lag in zip(plans, lags, strict=True):
            q, v = _joints(plan).sample([elapsed + lag])
            stopping = stop_path(q[0], v[0], a_max)
            before = _joints(plan).sample(np.linspace(elapsed, elapsed + lag, 5))
            own.append(JointPath(np.r_[np.linspace(0.0, lag, 5)[:-1], lag + stopping.times],
                                 np.vstack([before[0][:-1], stopping.positions]),
                                 np.vstack([before[1][:-1], stopping.velocities]))
                       if lag > 0.0 else stopping)
        return worst_force(own, times)

    at_once, staggered = own_stops([0.0, 0.0, 0.0]), own_stops([0.0, 0.02, 0.04])
    print(f'worst internal force: stopped along the path {along:.2f} N; each drive on its own '
          f'{at_once:.0f} N at one instant, {staggered:.0f} N reached 20 and 40 ms apart')
    assert along < 5.0
    assert staggered > 100.0


def _pivots() -> list[np.ndarray]:
    from test_coordinator import FAST, FakePositioner
    return list(Coordinator(CELL, MECH, [FakePositioner(e.name) for e in CELL.positioners],
                            FAST).pivots)
