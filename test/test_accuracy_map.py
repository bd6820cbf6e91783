"""The accuracy map (issue 25): a run program over a grid of poses
(positioning_cell.analysis.program ``grid:``, core.pose_grid), and the map of AP_p and RP_l
over them (positioning_cell.analysis.accuracy_map), its report section and plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from positioning_cell import names
from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.accuracy_map import MAP_LEAST, map_summary, mapped
from positioning_cell.analysis.plots import ACCURACY_MAP, draw_plots, plot_names
from positioning_cell.analysis.program import load_program, program_from
from positioning_cell.analysis.report import markdown
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.pose_grid import PoseGrid, grid_poses
from positioning_cell.errors import ConfigError
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

MECH = Mechanism.from_params(node_parameters(
    load_parameter_file(config_path('cell.yaml')), names.NODE_POSITIONER).get('mechanism', {}))
SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))


def test_the_shipped_map_program_is_a_grid_of_125_poses_within_the_limits() -> None:
    """config/accuracy_map.yaml: 5 × 5 × 5 poses over 20 × 20 × 16 mm, named G001..G125 in
    grid order (x slowest, z fastest), the corners where the box says."""
    program = load_program(config_path('accuracy_map.yaml'), MECH)
    assert len(program.names) == 125  # the issue asks 100 or more
    assert program.names[0] == 'G001' and program.names[-1] == 'G125'
    np.testing.assert_allclose(program.position.min(axis=0), [-0.01, -0.01, 0.188], atol=1e-12)
    np.testing.assert_allclose(program.position.max(axis=0), [0.01, 0.01, 0.204], atol=1e-12)
    np.testing.assert_allclose(program.position[1] - program.position[0], [0, 0, 0.004],
                               atol=1e-12)
    assert program.moves == 250


@pytest.mark.parametrize(('block', 'words'), [
    ({'grid': {'points': 3}, 'poses': {'P1': {'position': [0, 0, 0.196]}}}, 'not both'),
    ({'grid': {'points': 0}}, 'program.grid.points'),
    ({'grid': {'sideways': 1}}, 'sideways'),
    ({'grid': {'centre': [0.0, 0.0, 0.5]}}, 'no pose of the grid'),
    ({'grid': [1, 2]}, 'program.grid'),
])
def test_a_bad_grid_is_refused_with_its_key(block: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        program_from({'program': block}, MECH)


def test_the_grid_is_the_production_grid_and_leaves_out_what_it_cannot_reach() -> None:
    """One grid, two uses: a box larger than the workspace keeps only the poses within the
    mechanism's limits (fewer than the grid's)."""
    wide = PoseGrid(half_widths=(0.03, 0.03, 0.02), points=5)
    p, _ = grid_poses(MECH, wide)
    assert 0 < p.shape[0] < 125
    program = program_from({'program': {'grid': {'half_widths': [0.03, 0.03, 0.02],
                                                 'points': 5}}}, MECH)
    np.testing.assert_array_equal(program.position, p)


def test_a_run_over_a_grid_gives_the_map_its_section_and_its_plot(tmp_path: Path) -> None:
    """A synthetic run over 27 poses (two modes, two cycles): both modes mapped; the map's
    worst and mean are the per-pose figures'; the report has the section, the plots are the
    map instead of the per-pose ones, and the map is drawn."""
    p, q = grid_poses(MECH, PoseGrid(half_widths=(0.008, 0.008, 0.006), points=3))
    assert p.shape[0] == 27 and p.shape[0] >= MAP_LEAST
    run = synthetic_run(p, q, modes=('none', 'model'), cycles=2, dwell_time=1.5, seed=5)
    write_run_bag(tmp_path / 'bag', run)
    analysis = analyse_bag(tmp_path / 'bag', SETTINGS)
    assert [m.mode for m in mapped(analysis.modes)] == ['none', 'model']
    for m in analysis.modes:
        s = map_summary(m)
        ap = np.array([pose.figures.ap_p for pose in m.poses])
        rp = np.array([pose.figures.rp_l for pose in m.poses], dtype=float)
        assert s.poses == 27 and s.ap_p_max == ap.max() and s.ap_p_mean == pytest.approx(
            ap.mean(), rel=1e-12)
        assert s.rp_l_max == rp.max() and s.rp_l_worst == m.poses[int(np.argmax(rp))].pose
        np.testing.assert_allclose(s.low, p.min(axis=0), atol=1e-12)
        np.testing.assert_allclose(s.high, p.max(axis=0), atol=1e-12)
    text = markdown(analysis)
    assert '## Accuracy map' in text and '| none | 27 | -8.0 … 8.0 |' in text
    names_ = plot_names(analysis)
    assert ACCURACY_MAP in names_ and 'clusters.png' not in names_
    [png] = draw_plots(analysis, tmp_path / 'plots', [ACCURACY_MAP])
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 20_000


def test_a_run_of_few_poses_is_not_mapped(tmp_path: Path) -> None:
    """The ISO cube's five poses: no mode mapped, no section, the per-pose plots stay."""
    p = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                  [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])
    run = synthetic_run(p, np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)), modes=('model',), cycles=2,
                        dwell_time=1.5, seed=6)
    write_run_bag(tmp_path / 'bag', run)
    analysis = analyse_bag(tmp_path / 'bag', SETTINGS)
    assert len(analysis.modes[0].poses) == 5 and mapped(analysis.modes) == ()
    assert '## Accuracy map' not in markdown(analysis)
    assert plot_names(analysis) == ['error_over_time.png', 'axis_errors.png', 'clusters.png',
                                    'error_distribution.png']


def _png_size(path: Path) -> tuple[int, int]:
    """Width and height in pixels from a PNG's IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n' and data[12:16] == b'IHDR'
    return int.from_bytes(data[16:20], 'big'), int.from_bytes(data[20:24], 'big')


def test_the_clusters_plot_of_many_poses_wraps_into_rows(tmp_path: Path) -> None:
    """Thirteen poses (fewer than a map takes): six to a row, three rows, the last with one
    pose; 23 poses in one row drew 8096 × 704 px (issue 26)."""
    from positioning_cell.analysis.plots import CLUSTER_COLUMNS, CLUSTERS
    from positioning_cell.plotting import DPI

    k = np.arange(13)
    p = np.column_stack([0.002 * np.cos(k), 0.002 * np.sin(k), 0.196 + 0.0003 * k])
    run = synthetic_run(p, np.tile([0.0, 0.0, 0.0, 1.0], (13, 1)), modes=('model',),
                        cycles=2, dwell_time=1.5, seed=7)
    write_run_bag(tmp_path / 'bag', run)
    analysis = analyse_bag(tmp_path / 'bag', SETTINGS)
    assert len(analysis.modes[0].poses) == 13 < MAP_LEAST
    assert CLUSTERS in plot_names(analysis)
    [png] = draw_plots(analysis, tmp_path / 'plots', [CLUSTERS])
    # six 3.2 in columns, three rows of two panels (6.4 in a row), at the plots' resolution
    assert _png_size(png) == (round(CLUSTER_COLUMNS * 3.2 * DPI), round(3 * 6.4 * DPI))
