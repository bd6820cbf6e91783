"""A recorded bag tiled to N messages (positioning_cell.testing.tiled_bag, the input of
benchmarks/analysis_recorded.py): exactly N messages, every copy the source's messages with
log times, header stamps and marker times moved by one period per copy (so every time
increases from copy to copy), and it analyses as the program repeated: every visit, sample and
calibration run of the source once per copy. No ROS graph."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.replay import OUTSIDE_PROGRAM
from positioning_cell.bag import BagReader
from positioning_cell.names import PROGRAM
from positioning_cell.testing.tiled_bag import shift_marker, tile_bag

MAKE_RUN = Path(__file__).resolve().parent / 'data' / 'makerun' / 'bag'
NS = 1_000_000_000


def _times(path: Path) -> tuple[np.ndarray, dict[str, list[int]], list[str]]:
    """Log times (ns), each topic's header stamps (ns, messages with a header) and the
    program steps' JSON, in the bag's order."""
    logs, stamps, steps = [], defaultdict(list), []
    with BagReader(path) as reader:
        for m in reader.messages():
            logs.append(m.log_time_ns)
            header = getattr(m.message, 'header', None)
            if header is not None:
                stamps[m.topic].append(header.stamp.sec * NS + header.stamp.nanosec)
            if m.topic == PROGRAM:
                steps.append(m.message.data)
    return np.array(logs), stamps, steps


@pytest.fixture(scope='module')
def source() -> tuple[np.ndarray, dict[str, list[int]], list[str]]:
    return _times(MAKE_RUN)


def test_a_tiled_bag_holds_the_source_shifted_copy_after_copy(
        tmp_path: Path, source: tuple[np.ndarray, dict[str, list[int]], list[str]]) -> None:
    logs, stamps, steps = source
    n = len(logs)
    tiled = tile_bag(MAKE_RUN, tmp_path / 'tiled', 2 * n + 500)
    assert (tiled.message_count, tiled.copies, tiled.source_messages) == (2 * n + 500, 3, n)
    assert tiled.period_ns > logs[-1] - logs[0]
    got_logs, got_stamps, got_steps = _times(tiled.path)
    assert got_logs.shape == (2 * n + 500,) and np.all(np.diff(got_logs) >= 0)
    for k in range(2):
        assert_array_equal(got_logs[k * n:(k + 1) * n], logs + k * tiled.period_ns)
    assert_array_equal(got_logs[2 * n:], logs[:500] + 2 * tiled.period_ns)
    for topic, own in stamps.items():
        own_ns = np.array(own)
        mine = np.array(got_stamps[topic])
        moved = np.concatenate([np.where(own_ns > 0, own_ns + k * tiled.period_ns, 0)
                                for k in range(3)])[:mine.shape[0]]
        assert_array_equal(mine, moved, err_msg=topic)
        set_ = own_ns[own_ns > 0]
        if set_.size:  # copy k + 1 starts after copy k ends
            assert set_.max() < set_.min() + tiled.period_ns, topic
    for before, after in zip(steps, got_steps[len(steps):2 * len(steps)], strict=True):
        assert json.loads(after)['stamp'] == pytest.approx(
            json.loads(before)['stamp'] + tiled.period_ns / NS, abs=1e-6)


def test_a_tiled_bag_analyses_as_the_program_repeated(tmp_path: Path) -> None:
    """Two copies: every program visit twice, every sample twice, each calibration run twice
    under names of its own. The stored bag was recorded before programs marked their end, so
    the moves before the second program (the calibration and homing moves) follow a program
    step, the first program's last: they take its mode, by the analysis's labelling rule for
    such bags, and so are in that mode's visits (test_analysis: with the end marker they are
    outside every program)."""
    one = analyse_bag(MAKE_RUN)
    two = analyse_bag(tile_bag(MAKE_RUN, tmp_path / 'tiled', 2 * one.message_count).path)
    assert not two.problems and two.message_count == 2 * one.message_count
    assert len(two.replay.visits) == 2 * len(one.replay.visits)
    assert two.replay.measured.count == 2 * one.replay.measured.count
    assert two.replay.truth.count == 2 * one.replay.truth.count
    before = sum(v.mode == OUTSIDE_PROGRAM for v in one.replay.visits)
    last = one.replay.program[-1].mode
    counts = {m.mode: m.extremes.n for m in one.modes}
    assert {m.mode: m.extremes.n for m in two.modes} == {
        mode: 2 * n + (before if mode == last else 0) for mode, n in counts.items()}
    runs = [r.run for r in two.context.calibration_runs]
    assert len(set(runs)) == len(runs) == 2 * len(one.context.calibration_runs)


def test_a_tiled_bag_can_be_shorter_than_its_source(tmp_path: Path) -> None:
    assert tile_bag(MAKE_RUN, tmp_path / 'cut', 1000).message_count == 1000
    with pytest.raises(ValueError, match='at least 1'):
        tile_bag(MAKE_RUN, tmp_path / 'none', 0)


def test_marker_times_move_and_other_text_stays() -> None:
    moved = json.loads(shift_marker(
        '{"mode": "none", "stamp": 100.5, "run": "2026-12-03T09:18:00.026+00:00"}', 2 * NS))
    assert moved['stamp'] == pytest.approx(102.5)
    assert moved['run'] == '2026-12-03T09:18:02.026+00:00' and moved['mode'] == 'none'
    assert shift_marker('not json', NS) == 'not json'
    assert shift_marker('[1, 2]', NS) == '[1, 2]'
