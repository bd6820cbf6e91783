"""The coordinated cell's watch window without ROS (issue 27 item 6): what it waits for, the
internal force its load cells give against the panel simulator's truth, and what it draws.
On the running cell: test_coordinated_cell."""

from __future__ import annotations

import numpy as np
import pytest
from load_cell_truth import set_readings
from rich.console import Console

from positioning_cell.coordinated.panel_motion import platform_goals
from positioning_cell.coordinated.settings import CellCoordinatorSettings
from positioning_cell.parameters import parse
from positioning_cell.sim.panel import PanelTruth
from positioning_cell.tools.cell_watch_panel import render_panel
from positioning_cell.watch.panel import LOAD_CELL_READINGS, PanelWatchState
from positioning_cell.watch.state import Status

#: The coordinator as shipped: config/three_positioners.yaml, the nominal machine.
SETTINGS = parse(CellCoordinatorSettings, {})
CELL = SETTINGS.cell()
NAMES = ('p1', 'p2', 'p3')
NOW = 1.8e9


def _text(state: PanelWatchState, now: float = NOW) -> str:
    console = Console(record=True, width=160, color_system=None)
    console.print(render_panel(state.snapshot(), now))
    return console.export_text()


def _strained() -> tuple[np.ndarray, np.ndarray, float]:
    """The sets' encoders and load cells with p2 0.2 mm and p3 0.1 mm off the rigid panel,
    and the truth's largest internal force."""
    goals = platform_goals(CELL, SETTINGS.mechanism, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    misfit = np.array([[0.0, 0.0, 0.0], [2e-4, 0.0, 0.0], [0.0, 1e-4, 0.0]])
    return set_readings(PanelTruth(CELL, SETTINGS.mechanism),
                        [(p + d, q) for (p, q), d in zip(goals, misfit, strict=True)])


def test_before_anything_comes_it_says_what_it_waits_for() -> None:
    state = PanelWatchState()
    snapshot = state.snapshot()
    assert snapshot.names == () and 'not known yet' in str(snapshot.internal_force())
    text = _text(state)
    assert 'coordinator: no status yet' in text
    assert 'waiting for /panel/metrology/pose' in text
    assert 'waiting for /cell_coordinator cell_file' in text


def test_the_load_cells_give_the_truths_internal_force() -> None:
    state = PanelWatchState()
    state.coordinator_settings(SETTINGS)
    assert state.snapshot().names == NAMES
    joints, efforts, largest = _strained()
    for name, q, tau in zip(NAMES[:2], joints, efforts, strict=False):
        state.joints(name, q, tau)
    assert state.snapshot().internal_force() == 'no load cells heard of p3'
    state.joints('p3', joints[2], efforts[2])
    force = state.snapshot().internal_force()
    assert largest > 100.0 and force == pytest.approx(largest, rel=0.02)


def test_the_load_cells_are_averaged_over_the_latest_readings() -> None:
    state = PanelWatchState()
    state.coordinator_settings(SETTINGS)
    joints, efforts, _ = _strained()
    for k in range(3 * LOAD_CELL_READINGS):  # noise about the strained readings
        sign = 1.0 if k % 2 else -1.0
        for name, q, tau in zip(NAMES, joints, efforts, strict=True):
            state.joints(name, q, tau + sign * 5.0)
    snapshot = state.snapshot()
    assert all(len(snapshot.readings[n][0]) == LOAD_CELL_READINGS for n in NAMES)
    np.testing.assert_allclose(snapshot.readings['p2'][1].mean(axis=0), efforts[1], atol=1e-9)


def test_it_draws_the_coordinator_the_panel_the_force_and_every_positioner() -> None:
    state = PanelWatchState()
    state.coordinator_settings(SETTINGS)
    state.coordinator(Status(0, 'idle', NOW, {'state': 'idle', 'last_code': 'success',
                                              'last_reason': 'every positioner settled'}))
    turned = [0.0, 0.0, np.sin(0.002), np.cos(0.002)]  # 4 mrad about z
    state.panel((np.array([0.6, 0.3, 0.25]), np.array(turned)), NOW - 0.1)
    joints, efforts, largest = _strained()
    for name, q, tau in zip(NAMES, joints, efforts, strict=True):
        state.joints(name, q, tau)
        state.set_status(name, positioner=Status(0, 'settled', NOW, {'state': 'settled'}),
                         drives=Status(0, 'holding', NOW, {'enabled': 'true',
                                                           'state': 'holding'}))
    state.set_status('p3', drives=Status(2, 'fault', NOW, {'enabled': 'false',
                                                          'state': 'fault'}))
    text = _text(state)
    assert 'coordinator: OK idle' in text and 'last: success: every positioner settled' in text
    assert 'x y z +600.0000 +300.0000 +250.0000 mm' in text and '+4.000 mrad' in text
    assert 'measured 0.10 s ago' in text and 'STALE' not in text
    assert f'{largest:.0f} N at most at one attachment' in text
    rows = {line.split()[1]: line for line in text.splitlines()
            if line.strip().startswith(('│ p', '| p'))}
    assert set(rows) == set(NAMES), text
    assert 'settled' in rows['p1'] and 'on (holding)' in rows['p1']
    assert 'OFF (fault)' in rows['p3']
    assert 'STALE' in _text(state, NOW + 5.0)  # an old panel reading says so
