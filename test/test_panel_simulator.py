"""The panel simulator's cycle (simulation truth, no ROS): the sets' true poses, each on its
own stream at its own instants, taken at one instant; a panel moving as one rigid body then
shows no stretch, where the latest pose of each would part its attachments by the distance
the panel travels between their stamps."""

from __future__ import annotations

import numpy as np
import pytest

from positioning_cell.coordinated.panel_motion import pair_disagreement, platform_goals
from positioning_cell.sim.cell_installation import InstallationSettings
from positioning_cell.sim.panel_simulator import PanelSimulator, PanelSimulatorSettings

#: The shipped three-positioner cell installed exactly as its file says.
SETTINGS = PanelSimulatorSettings(installation=InstallationSettings(
    base_position_sigma=0.0, base_angle_sigma=0.0, socket_sigma=0.0))
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
SPEED = 0.01  # m/s, the panel along the cell's x
PERIOD = 0.02  # s, each set's true pose stream (50 Hz)
PHASES = (0.0, 0.007, 0.013)  # s, each set's stream's offset


def _poses_at(sim: PanelSimulator, t: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each positioner's platform (its base) holding the panel at SPEED·t along x."""
    return platform_goals(sim.cell, SETTINGS.mechanism, [SPEED * t, 0.0, 0.0], IDENTITY)


def test_a_cycle_takes_every_set_at_one_instant() -> None:
    sim = PanelSimulator(SETTINGS)
    assert sim.names == ('p1', 'p2', 'p3')
    latest = {}
    for k, name in enumerate(sim.names):
        assert sim.cycle() is None  # not every set yet
        for t in np.arange(10) * PERIOD + PHASES[k]:
            sim.true_pose(name, 100.0 + t, *_poses_at(sim, t)[k])
        latest[name] = 100.0 + t
    cycle = sim.cycle()
    assert cycle is not None
    assert cycle.stamp == min(latest.values())
    assert cycle.stamp == pytest.approx(100.0 + 9 * PERIOD)
    record = cycle.forces_record()
    assert record['largest_stretch_um'] < 1e-3
    assert [s['pair'] for s in record['stretches']] == [['p1', 'p2'], ['p1', 'p3'],
                                                         ['p2', 'p3']]
    # The latest poses of each, as they were taken before: the panel stretched by what it
    # travels between their stamps (10 mm/s × up to 13 ms).
    naive = [_poses_at(sim, 9 * PERIOD + PHASES[k])[k] for k in range(3)]
    apart = max(abs(d.stretch) for d in pair_disagreement(sim.installation.true_cell,
                                                          SETTINGS.mechanism, naive))
    assert apart > 30e-6
    # The panel the cycle describes is where it was at that instant (its weight's sag aside).
    expected = SPEED * (cycle.stamp - 100.0)
    assert cycle.state.panel.p[0] == pytest.approx(expected, abs=1e-7)


def test_a_restarted_stream_starts_again() -> None:
    sim = PanelSimulator(SETTINGS)
    for k, name in enumerate(sim.names):
        sim.true_pose(name, 50.0, *_poses_at(sim, 0.0)[k])
    sim.true_pose('p2', 10.0, *_poses_at(sim, 0.0)[1])  # a set restarted: its clock older
    cycle = sim.cycle()
    assert cycle is not None and cycle.stamp == 10.0
