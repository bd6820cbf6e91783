"""The leg driver as a process, commanded by this test (its ``command.commander``), probed as
issue 21 probed it (positioning_cell.ros.driver_probes): a trajectory stamped 0.6 s in the
past is refused as too old (it used to be accepted, then fault the drive), one stamped 4 s
ahead as too far in the future; a 100 000-point trajectory is refused before its points are
read and a 50 000-point one is taken, and neither holds up the encoder publication (it used to
stall 1.49 s); SIGINT then stops the driver (the 2 s
target: benchmarks/shutdown.py).

Multi-process tier: the driver runs in its own process, so the time this test spends building
its big messages does not hold it up; its publication is judged from the stamps it gives (its
own clock), not from when this process received them. benchmarks/faults.py prints the times."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from positioning_cell.names import DRIVER
from positioning_cell.ros.driver_probes import PROBES, CommandedDriver

pytestmark = [pytest.mark.nodes, pytest.mark.slow, pytest.mark.timing]

#: Largest interval between two encoder publications the driver may leave while it takes a
#: command (its period is 0.01 s; a loaded 2-core machine delays a timer by tens of ms; the
#: positioner calls the driver lost after 0.2 s).
LARGEST_GAP_S = 0.15
#: A stop that hangs fails here; the 2 s target of issue 21 is benchmarks/shutdown.py's.
STOP_BOUND_S = 5.0


def test_the_commanders_probes(tmp_path: Path) -> None:
    driver = CommandedDriver(tmp_path)
    try:
        for probe in PROBES:
            result = driver.probe(probe)
            print(result.line())
            assert result.expected, result
            assert result.largest_gap_s < LARGEST_GAP_S, result
    finally:
        started = time.monotonic()
        codes = driver.close()
    assert codes == {DRIVER.executable: 0}
    assert time.monotonic() - started < STOP_BOUND_S
