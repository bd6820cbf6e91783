"""A bag replayed by bag_player_node into a live accuracy_monitor_node gives the figures
analyze_bag computes from that bag offline."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cell_harness import Client, ProcessGroup, isolated_domain, wait_until
from std_srvs.srv import Trigger

from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import analyse_bag
from positioning_cell.config import config_path
from positioning_cell.names import DIAGNOSTICS, MEASURED_POSE, TARGET, TRUE_POSE
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

#: The player, the monitor and a client on a private domain.
pytestmark = pytest.mark.nodes


def _numbers(poses: list[dict[str, object]]) -> np.ndarray:
    out: list[float] = []
    for pose in poses:
        for key in sorted(pose):
            value = pose[key]
            if isinstance(value, list):
                out.extend(float(v) for v in value)
            else:
                out.append(math.nan if value is None else float(value))  # type: ignore[arg-type]
    return np.array(out)


def test_the_live_monitor_fed_by_the_player_reports_the_offline_figures(tmp_path: Path) -> None:
    positions = [[0.0, 0.0, 0.196], [0.004, 0.004, 0.2]]
    quaternions = [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]]
    # In ``measured`` mode each move pauses 200 µm off before its correction: the monitor
    # judges the final settled window, after the positioner's move end (/diagnostics).
    pause = 200e-6
    run = synthetic_run(positions, quaternions, modes=('model', 'measured'), cycles=2,
                        dwell_time=2.5, seed=3, pause={'measured': pause})
    bag = tmp_path / 'bag'
    write_run_bag(bag, run)
    offline = analyse_bag(bag, MonitorSettings.from_file(config_path('cell.yaml'))).monitor
    assert sum(offline['verdicts'].values()) == 8 and len(offline['measured']['poses']) == 2
    for visit, end, step in zip(offline['truth']['visits'], run.end_time, run.steps,
                                strict=True):
        error = np.linalg.norm(np.subtract(visit['position'], visit['commanded_position']))
        assert visit['window_start'] >= end and (step.mode != 'measured' or error < pause / 10)

    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as group, \
            Client(domain) as client:
        group.start('accuracy_monitor_node')
        client.call(Trigger, '/accuracy_monitor/report', Trigger.Request())  # it is up
        player = group.start('bag_player_node', overrides={'bag_player': {
            'bag': str(bag), 'rate': 2.0, 'wait_for_subscribers_s': 20.0,
            'topics': [TARGET, MEASURED_POSE, TRUE_POSE, DIAGNOSTICS]}})
        assert player.wait(timeout=60.0) == 0, group.log('bag_player_node')

        def report() -> dict[str, Any]:
            return json.loads(client.call(Trigger, '/accuracy_monitor/report',
                                          Trigger.Request()).message)

        # The player is done once DDS has delivered; the monitor may still be working through
        # its queue: wait until it has paired every measurement with its truth.
        pairs = offline['tracker']['samples']
        latest: dict[str, Any] = {}

        verdicts = sum(offline['verdicts'].values())

        def all_paired() -> bool:  # the move ends (/diagnostics) may come after the poses
            latest.update(report())
            return (bool(latest['tracker']) and latest['tracker']['samples'] >= pairs
                    and sum(latest['verdicts'].values()) >= verdicts)

        wait_until(all_paired, 30.0, f'the monitor to have paired all {pairs} tracker samples '
                   f'and judged {verdicts} visits')
        live = latest

    assert live['verdicts'] == offline['verdicts']
    # each visit's U from the covariances the bag's readings state, read the same way
    assert live['decisions'] == offline['decisions']
    assert offline['decisions']['conforms'] > 0
    for source in ('measured', 'truth'):
        assert len(live[source]['visits']) == len(offline[source]['visits']) == 8
        np.testing.assert_allclose(_numbers(live[source]['poses']),
                                   _numbers(offline[source]['poses']), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(_numbers(live[source]['visits']),
                                   _numbers(offline[source]['visits']), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(_numbers([live['tracker']]), _numbers([offline['tracker']]),
                               rtol=1e-12)
