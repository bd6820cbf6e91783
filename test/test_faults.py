"""The fault matrix on the live cell (positioning_cell.procedures.fault_trials over
positioning_cell.ros.fault_cell; docs/reference/fault-matrix.md is generated from the
procedure's table): each injected fault gives the reaction written HERE (result code, words
of the reason) within its time bound, the drives stop (checked on
/sim/legs/true_joint_states), and no axis goes beyond a limit. The expectations are this
test's own, compared with what the trial received, so a wrong expectation in the procedure's
table is caught too.

Multi-process tier: one cell (the four nodes and the recorder) on a private domain for the
module, homed; each fault is one trial on it, the cell made ready before and restored after.
benchmarks/faults.py runs 20 trials of each and prints the reaction times.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from cell_harness import stop_cleanly
from fault_expectations import EXPECTED

from positioning_cell.procedures.fault_trials import FAULTS, fault, run_trial
from positioning_cell.ros.fault_cell import FaultCell

pytestmark = [pytest.mark.nodes, pytest.mark.slow, pytest.mark.timing]

@pytest.fixture(scope='module')
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FaultCell]:
    with FaultCell(tmp_path_factory.mktemp('faults')) as cell:
        cell.start()
        yield cell
        stop_cleanly(cell.procs)


def test_every_fault_has_its_expectation_here() -> None:
    assert sorted(EXPECTED) == sorted(f.name for f in FAULTS)


@pytest.mark.parametrize('name', [f.name for f in FAULTS])
def test_fault_gets_its_reaction_in_time(cell: FaultCell, name: str) -> None:
    trial = run_trial(cell, fault(name))
    print(f'{name}: {trial.code} in {trial.reaction_s:.3f} s; {trial.reason}')
    logs = {k: cell.procs.log(k)[-1500:] for k in cell.procs.procs}
    expected = EXPECTED[name]
    if expected is None:
        answered, calls = trial.code.split(' answered')[0].split('/')
        assert answered == calls, (trial, logs)
    else:
        codes, words = expected
        assert trial.code in codes, (trial, logs)
        assert words in trial.reason, (trial, logs)
    assert trial.reaction_s <= fault(name).bound_s, trial
    assert trial.ok, (trial, logs)
    assert trial.within_limits
