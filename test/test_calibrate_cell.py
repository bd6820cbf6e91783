"""calibrate_cell's command line without a cell (the live run and --from-bag on its recording
are exercised end to end by test_run_cell, whose run calibrates the cell first)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from cell_harness import executable

#: Runs the calibrate_cell executable in a process of its own.
pytestmark = pytest.mark.nodes


def test_from_bag_refuses_what_is_not_a_bag(tmp_path: Path) -> None:
    proc = subprocess.run([executable('calibrate_cell'), '--from-bag', str(tmp_path / 'none'),
                           '--out', str(tmp_path / 'o')], capture_output=True, text=True,
                          timeout=60.0, check=False)
    assert proc.returncode == 2 and 'calibrate_cell: error:' in proc.stdout, proc.stdout
    assert not (tmp_path / 'o').exists()


def test_from_bag_refuses_a_bag_without_a_calibration_run(tmp_path: Path) -> None:
    from test_package import one_message_bag
    bag = one_message_bag(tmp_path / 'bag')
    proc = subprocess.run([executable('calibrate_cell'), '--from-bag', str(bag), '--out',
                           str(tmp_path / 'o')], capture_output=True, text=True, timeout=60.0,
                          check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert ('not a calibration run: no /cell/calibration, /legs/joint_states, /metrology/pose'
            in proc.stdout), proc.stdout
    assert not (tmp_path / 'o').exists()
