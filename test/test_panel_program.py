"""The coordinated cell's program and its analysis (positioning_cell.procedures.panel_program,
positioning_cell.analysis.panel), without ROS: the shipped program file and bad ones, the
program driven on a port whose panel lands off its goal by a known error and whose tracker
reads it shifted by a known offset, and the ISO 9283 figures, errors and forces the analysis
draws from what such a run records, checked against those known errors."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from positioning_cell.accuracy.iso9283 import iso9283
from positioning_cell.analysis import panel
from positioning_cell.analysis.panel import (
    PanelForces,
    PanelRecording,
    StampedPoses,
    panel_figures,
    report_lines,
)
from positioning_cell.config import config_path
from positioning_cell.coordinated.cell_file import load
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.procedures import panel_program
from positioning_cell.procedures.panel_program import PanelStep, load_panel_program
from positioning_cell.procedures.port import Moved

MECH = Mechanism.default()
CELL = load(config_path('three_positioners.yaml'))
CENTRE = CELL.panel_points(MECH).mean(axis=0)
PROGRAM = load_panel_program(config_path('panel_program.yaml'))
#: Where the fake cell really puts the panel: T_true = T_goal · ERROR (a turn and a shift).
ERROR = Transform(np.array([3e-5, -2e-5, 1e-5]), Rotation.from_rotvec([2e-5, 0.0, -1e-5])
                  .as_matrix())
#: How the fake tracker reads it: shifted by this in the cell frame, m.
SHIFT = np.array([4e-6, 0.0, -3e-6])
READING_HZ, TRUTH_HZ = 20.0, 50.0


class FakeCell:
    """A panel port on a clock of its own: each move takes a second and lands at goal · ERROR
    (``refuse``: the step numbers refused); the tracker reads at READING_HZ, the truth at
    TRUTH_HZ, the internal forces at 10 Hz (larger while moving)."""

    def __init__(self, refuse: tuple[int, ...] = ()) -> None:
        self.t, self.moves, self.refuse = 100.0, 0, refuse
        self.panel = Transform.identity()
        self.readings: list[list[float]] = []
        self.truth: list[list[float]] = []
        self.forces: list[tuple[float, float, float]] = []

    def now(self) -> float:
        return self.t

    def _hold(self, until: float, force: float, stretch: float) -> None:
        """The panel held where it is from now to ``until``: truth and forces recorded."""
        for t in np.arange(self.t, until, 1.0 / TRUTH_HZ):
            self.truth.append([t, *self.panel.p, *self.panel.q])
        for t in np.arange(self.t, until, 0.1):
            self.forces.append((t, force, stretch))
        self.t = until

    def move_panel(self, position: Any, quaternion: Any, speed_scale: float = 0.0) -> Moved:
        self.moves += 1
        self._hold(self.t + 1.0, 80.0, 6e-6)  # moving
        if self.moves in self.refuse:
            return Moved(False, 'refused_limits', 'p2: leg 1 beyond its travel')
        self.panel = Transform.from_pq(position, quaternion) @ ERROR
        return Moved(True, 'success', '')

    def panel_readings(self, count: int, since: float | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        start = self.t if since is None else since
        # one reading stamped before the window (the move's last): never taken
        self.readings.append([start - 0.01, *(self.panel.p + 1e-3), *self.panel.q])
        stamps = start + 0.005 + np.arange(count) / READING_HZ
        self._hold(float(stamps[-1]) + 0.1, 10.0, 1e-6)  # at rest
        for t in stamps:
            self.readings.append([float(t), *(self.panel.p + SHIFT), *self.panel.q])
        taken = np.array(self.readings[-count:])
        return taken[:, 1:4], taken[:, 4:8]

    def recording(self, steps: list[PanelStep]) -> PanelRecording:
        def stamped(rows: list[list[float]]) -> StampedPoses:
            a = np.array(sorted(rows))
            return StampedPoses(a[:, 0], a[:, 1:4], a[:, 4:8])

        f = np.array(self.forces)
        return PanelRecording(steps, stamped(self.readings), stamped(self.truth),
                              PanelForces(f[:, 0], f[:, 1], f[:, 2]))


def _run(port: FakeCell) -> tuple[list[PanelStep], list[PanelStep], list[str]]:
    recorded: list[PanelStep] = []
    said: list[str] = []
    steps = panel_program.run(port, CELL, MECH, PROGRAM, recorded.append, said.append)
    return steps, recorded, said


def test_the_shipped_program() -> None:
    assert PROGRAM.names == ('P1', 'P2', 'P3', 'P4', 'P5')
    assert PROGRAM.steps == 15 and PROGRAM.settings.readings == 10
    assert PROGRAM.calibration.poses == 12
    assert PROGRAM.positioners.enabled and PROGRAM.positioners.poses == 20
    poses = panel_program.program_poses(CELL, MECH, PROGRAM)
    np.testing.assert_allclose(poses[0].apply(CENTRE), CENTRE, atol=1e-15)  # P1: home
    for row, pose in zip(PROGRAM.moves, poses, strict=True):
        # the test point moved by the row's move, the panel turned by its rotation vector
        np.testing.assert_allclose(pose.apply(CENTRE), CENTRE + row[:3], atol=1e-15)
        np.testing.assert_allclose(Rotation.from_matrix(pose.R).as_rotvec(), row[3:],
                                   atol=1e-15)


@pytest.mark.parametrize(('doc', 'says'), [
    ({}, 'poses: expected a mapping'),
    ({'poses': {'P1': [0.0] * 5}}, r'poses.P1: expected \[x, y, z'),
    ({'poses': {'P1': [0.0, 0.0, 0.2, 0.0, 0.0, 0.0]}}, 'poses.P1: .* within'),
    ({'poses': {'P1': [0.0, 0.0, '.nan', 0.0, 0.0, 0.0]}}, 'poses.P1: expected'),
    ({'poses': {'P1': [0.0] * 6}, 'panel_program': {'cycles': 0}}, 'panel_program.cycles'),
    ({'poses': {'P1': [0.0] * 6}, 'panel_program': {'cycle': 2}}, 'panel_program.cycle'),
    ({'poses': {'P1': [0.0] * 6}, 'panel_calibration': {'poses': 2}}, 'panel_calibration.poses'),
    ({'poses': {'P1': [0.0] * 6}, 'positioner_calibration': {'hold_out': -1}},
     'positioner_calibration.hold_out'),
])
def test_a_bad_program_file_is_refused_naming_the_key(tmp_path: Path, doc: dict[str, Any],
                                                      says: str) -> None:
    path = tmp_path / 'program.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=f'{path}: .*{says}'):
        load_panel_program(path)


def test_a_step_travels_as_json_also_when_it_failed() -> None:
    steps, recorded, _ = _run(FakeCell(refuse=(2,)))
    assert recorded == steps
    for step in steps[:2]:
        again = PanelStep.from_json(step.to_json())
        assert again.to_json() == step.to_json()
    assert not steps[1].succeeded and math.isnan(PanelStep.from_json(
        steps[1].to_json()).measured_position[0])
    with pytest.raises(InputError, match='not a panel program step'):
        PanelStep.from_json('{"cycle": 1}')


def test_the_program_measures_every_pose_in_every_cycle() -> None:
    port = FakeCell(refuse=(7,))
    steps, _, said = _run(port)
    assert [(s.cycle, s.pose) for s in steps] == [
        (c, n) for c in (1, 2, 3) for n in PROGRAM.names]
    assert [s.succeeded for s in steps].count(False) == 1 and steps[6].code == 'refused_limits'
    assert said[6] == 'cycle 2 P2: refused_limits: p2: leg 1 beyond its travel'
    # a measured pose: the true one read through the shift; said at the test point
    off = np.linalg.norm(ERROR.apply(CENTRE) - CENTRE + SHIFT) * 1e6  # R_goal turns it only
    assert said[0] == f'cycle 1 P1: measured {off:.1f} um from its goal at the panel centre'
    goal = Transform.from_pq(steps[3].commanded_position, steps[3].commanded_quaternion)
    np.testing.assert_allclose(steps[3].measured_position, (goal @ ERROR).p + SHIFT, atol=1e-12)


def test_the_analysis_finds_the_known_errors() -> None:
    port = FakeCell(refuse=(7,))
    steps, _, _ = _run(port)
    figures = panel_figures(port.recording(steps))
    assert figures.same_as_live and figures.poses == PROGRAM.names
    np.testing.assert_allclose(figures.test_point, CENTRE, atol=1e-15)
    assert figures.steps == 15 and figures.failed == ('cycle 2 P2: refused_limits',)
    # the tracker's error: its shift, at every step
    np.testing.assert_allclose(figures.errors_m, np.linalg.norm(SHIFT), atol=1e-12)
    # the truth's: the test point carried by ERROR and turned with the goal (its length kept)
    np.testing.assert_allclose(figures.command_errors_m,
                               np.linalg.norm(ERROR.apply(CENTRE) - CENTRE), atol=1e-12)
    assert [f.n for f in figures.measured] == [3, 2, 3, 3, 3]
    poses = panel_program.program_poses(CELL, MECH, PROGRAM)
    for goal, m, t in zip(poses, figures.measured, figures.truth, strict=True):
        # a second computation: ISO 9283 of the known true test point, readings and truth
        true = goal @ ERROR
        expected = iso9283(goal.apply(CENTRE), goal.q, [true.apply(CENTRE)] * t.n,
                           [true.q] * t.n)
        assert t.ap_p == pytest.approx(expected.ap_p, abs=1e-12)
        np.testing.assert_allclose(np.array(m.barycentre) - t.barycentre, SHIFT, atol=1e-12)
        assert t.rp_l == pytest.approx(0.0, abs=1e-12)
        assert m.ap_a == pytest.approx(t.ap_a, abs=1e-12)
    assert figures.moving == (80.0, 6e-6) and figures.at_rest == (10.0, 1e-6)
    lines = report_lines(figures)
    assert lines[2].startswith('| pose | n | AP_p um') and len(lines) == 4 + 5 + 2 + 1
    assert lines[-1] == 'failed: cycle 2 P2: refused_limits'
    assert 'WARNING' not in '\n'.join(lines)


def test_the_analysis_says_what_the_bag_lacks() -> None:
    port = FakeCell()
    steps, _, _ = _run(port)
    whole = port.recording(steps)
    cut = whole.readings.window(0.0, steps[-1].settled + 0.2)  # the last step's readings lost
    with pytest.raises(InputError, match='cycle 3 P5: the bag holds 4 readings after the move'):
        panel_figures(whole._replace(readings=cut))
    with pytest.raises(InputError, match='no true panel pose'):
        panel_figures(whole._replace(truth=whole.truth.window(0.0, 0.0)))
    refused, _, _ = _run(FakeCell(refuse=tuple(range(1, 16))))
    with pytest.raises(InputError, match='no panel move of the program settled'):
        panel_figures(whole._replace(steps=refused))
    # a reading that differs from the one the run took: said, not hidden (index 0 is the
    # reading before the first window)
    moved = whole.readings.positions.copy()
    moved[1] += 1e-6
    changed = whole._replace(readings=whole.readings._replace(positions=moved))
    assert not panel_figures(changed).same_as_live
    assert panel.SAME_MEAN_M < 1e-6
