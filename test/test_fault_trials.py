"""The fault matrix's trials (positioning_cell.procedures.fault_trials) in process, without
DDS: the same procedure and judging as the live matrix (test/test_faults.py), on
positioning_cell.testing.instant_faults (the positioner's Mover driving the leg driver's own logic
and the simulated tracker, on the monotonic clock). Each fault that can be made without DDS
gives the result code and reason words written here; the trials that need DDS (a second
publisher, a flood of service calls) are refused by the port as Unsupported."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import pytest
from fault_expectations import IN_PROCESS, LIVE_ONLY

from positioning_cell import names
from positioning_cell.polling import wait_until
from positioning_cell.procedures.fault_port import Unsupported
from positioning_cell.procedures.fault_trials import (
    ATTEMPTS,
    FAULTS,
    DrivesOff,
    LandedLateError,
    fault,
    moving,
    ready,
    run_trial,
    silence_stop,
    start_move,
)
from positioning_cell.testing.instant_faults import InstantFaultPort


@pytest.fixture(scope='module')
def port(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InstantFaultPort]:
    with InstantFaultPort.configured(tmp_path_factory.mktemp('instant_faults')) as port:
        yield port


def test_every_fault_is_run_here_or_live_only() -> None:
    assert sorted([*IN_PROCESS, *LIVE_ONLY]) == sorted(f.name for f in FAULTS)


@pytest.mark.parametrize('name', list(IN_PROCESS))
def test_fault_gets_its_reaction_in_process(port: InstantFaultPort, name: str) -> None:
    trial = run_trial(port, fault(name))
    print(f'{name}: {trial.code} in {trial.reaction_s:.3f} s; {trial.reason}')
    codes, words = IN_PROCESS[name]
    assert trial.code in codes, trial
    assert words in trial.reason, trial
    # the reaction as expected; its time is test_faults' (the timing tier, alone on the
    # machine): here, beside the parallel tier's load, 0.305 s against 0.3 s was seen once
    assert not trial.problems, trial
    assert trial.within_limits


@pytest.mark.parametrize('name', LIVE_ONLY)
def test_the_dds_faults_are_refused_in_process(port: InstantFaultPort, name: str) -> None:
    with pytest.raises(Unsupported):
        run_trial(port, fault(name))


def test_a_move_that_never_starts_is_named_not_waited_for(port: InstantFaultPort) -> None:
    """A trial whose move is refused before anything moves (here the drives are switched off
    just before it) ends at once with the refusal, after its attempts, not on the 30 s wait
    for motion."""
    trial = run_trial(port, replace(fault('encoder frozen'), prepare=(DrivesOff(),)))
    assert len(trial.problems) == 1, trial
    assert trial.problems[0].startswith('the move ended before any axis moved: '), trial
    assert 'drives disabled' in trial.problems[0], trial
    assert trial.problems[0].endswith(f'in all {ATTEMPTS} attempts'), trial


def test_a_trial_begins_with_the_axes_at_rest(port: InstantFaultPort) -> None:
    """After the driver-killed trial the restarted driver is homed, and homing can end with an
    axis still settling (a second U angle at 1e-5 rad/s). The next trial took that for the
    motion of its own move, although the drives refused it (the CI failure of 2026-12-03):
    ready returns only with every axis at rest."""
    run_trial(port, fault('driver killed'))
    ready(port, 'none')
    returned = port.monotonic() - 0.1
    wait_until(lambda: len(port.true_states(returned).times) >= 10, 10.0, 'true joint states')
    assert not moving(port, returned)


def test_a_kill_after_the_move_ended_is_a_late_landing_not_a_wait(
        port: InstantFaultPort) -> None:
    """The commander killed once its move had ended (what a loaded machine can make of the
    trial's kill): the drives had nothing to stop, so the trial says it landed late (and
    run_trial tries again) instead of waiting 11 s for a stop that cannot come (the CI
    failure of 2026-12-03)."""
    killed = fault('positioner killed')
    ready(port, killed.mode)
    move = start_move(port)
    move.thread.join(timeout=30.0)
    assert move.outcome and move.outcome[0].success, move.outcome
    at = port.monotonic()
    port.kill(names.NODE_POSITIONER)
    try:
        with pytest.raises(LandedLateError, match='nothing to stop'):
            silence_stop(port, at, killed.bound_s)
    finally:
        killed.restore(port)

