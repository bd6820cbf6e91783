"""The fault matrix (positioning_cell.tools.fault_matrix, the docs' reference page
docs/reference/fault-matrix.md, generated from it): each
injected fault gives its expected reaction (result code, reason words) within its time bound,
the drives stop (checked on /sim/legs/true_joint_states), and no axis goes beyond a limit.

Multi-process tier: one cell (the four nodes and the recorder) on a private domain for the
module, homed; each fault is one trial on it, the cell made ready before and restored after.
benchmarks/faults.py runs 20 trials of each and prints the reaction times.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from positioning_cell.tools.fault_matrix import FAULTS, FaultCell, fault, run_trial

pytestmark = [pytest.mark.nodes, pytest.mark.slow]


@pytest.fixture(scope='module')
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FaultCell]:
    with FaultCell(tmp_path_factory.mktemp('faults')) as cell:
        cell.start()
        yield cell
        codes = cell.procs.stop()
        assert all(c == 0 for c in codes.values()), {k: cell.procs.log(k)[-2000:]
                                                     for k in codes}


@pytest.mark.parametrize('name', [f.name for f in FAULTS])
def test_fault_gets_its_reaction_in_time(cell: FaultCell, name: str) -> None:
    trial = run_trial(cell, fault(name))
    print(f'{name}: {trial.code} in {trial.reaction_s:.3f} s; {trial.reason}')
    assert trial.ok, (trial, {k: cell.procs.log(k)[-1500:] for k in cell.procs.procs})
    assert trial.within_limits
