"""The positioner's state log (positioning_cell.motion.state_log): each state logged once while
it lasts, whoever reports it, from any thread; refusals each time."""

from __future__ import annotations

import threading
import time

from positioning_cell.motion.state_log import StateLog

FAULT = 'fault: drive fault: following error on leg2_length: 1.043 mm exceeds the limit'


class SlowToCompare(str):
    """A message whose comparison gives the GIL up for a moment: the window in which another
    reporter's thread runs (in the node, the log call came between the check and the note)."""

    def __ne__(self, other: object) -> bool:
        time.sleep(0.001)
        return str.__ne__(self, other)

    def __eq__(self, other: object) -> bool:
        time.sleep(0.001)
        return str.__eq__(self, other)

    __hash__ = str.__hash__


def test_a_state_is_logged_once_while_it_lasts_and_again_after_an_ok() -> None:
    log = StateLog()
    assert log.logs('error', FAULT)
    # its 1 Hz re-publication, then the aborted move's report of the same state
    assert not log.logs('error', FAULT) and not log.logs('error', FAULT)
    assert log.logs('warn', 'aborted: stopped by /positioner/stop')  # another state
    assert not log.logs('ok', 'idle: ready')  # ok is never logged ...
    assert log.logs('warn', 'aborted: stopped by /positioner/stop')  # ... and ends the state


def test_each_refusal_is_logged() -> None:
    log = StateLog()
    refused = 'refused (refused_limits): jog leg1_length: step 50 mm exceeds the largest 5 mm'
    assert log.logs('warn', refused, each=True) and log.logs('warn', refused, each=True)


def test_reporters_on_several_threads_log_a_state_once() -> None:
    """The driver's status and the move's end report one fault at the same instant (seen: two
    warnings 4 ms apart under load): one of them logs it."""
    def report(log: StateLog, start: threading.Barrier, said: list[bool]) -> None:
        start.wait()
        said.append(log.logs('error', SlowToCompare(FAULT)))

    for round_ in range(20):
        log, start = StateLog(), threading.Barrier(6)
        said: list[bool] = []
        threads = [threading.Thread(target=report, args=(log, start, said)) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert said.count(True) == 1, (round_, said)
