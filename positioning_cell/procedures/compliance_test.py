"""The static compliance test on a running cell (ISO 9283:1998 §10; the test and its figures:
:mod:`positioning_cell.analysis.compliance_test`), through a
:class:`~positioning_cell.procedures.port.CellPort`: ``run_cell`` with a program's
``compliance:`` block, or the in-process cell of the tests.

With the positioner in mode ``none`` (put back afterwards: the load moves the platform, the
compensation has nothing to add), per load direction: a move to the test pose, then per step
the load rig commanded that step's load along the direction (the procedure waits for its load
cell to read it), the dwell, and ``samples`` tracker readings stamped from then on, averaged;
the marker of the step (its position and the independent part of its covariance: the
registration the readings share leaves the displacements) goes out on
``/cell/compliance_test`` and, after the direction's last step, a line with its compliance.
The rig is unloaded after each direction and however the test ends.

The platform's yield under the load is motion the positioner did not command: its standstill
watch (``standstill.tracker_position_tolerance``) faults a displacement beyond its tolerance
and stops the drives. The move that starts the next direction, and the one after the last,
then fail with the positioner's reason, and so does the test: choose the largest load so that
the platform stays within that tolerance.
"""

from __future__ import annotations

import datetime

import numpy as np

from positioning_cell import names
from positioning_cell.accuracy.compliance import DIRECTIONS, static_compliance
from positioning_cell.analysis.compliance_test import ComplianceMarker, ComplianceTest
from positioning_cell.motion.settings import CompensationMode
from positioning_cell.moves.correction import mean_reading
from positioning_cell.procedures.port import (
    CellPort,
    FloatArray,
    Readings,
    Say,
    in_mode,
    moved_or_raise,
    say_recorded,
)


def averaged(r: Readings) -> tuple[FloatArray, FloatArray]:
    """The mean position (3,) m of a window of readings and the independent part (3, 3) m² of
    its covariance: without the published registration's (the part every reading shares);
    with no registration published, the whole covariance of the mean (an upper bound)."""
    common = (None if r.registration is None
              else r.registration.covariance_at(r.position.mean(axis=0))[0])
    p, _, cov = mean_reading(r.position, r.quaternion, r.covariance, common)
    own = cov[:3, :3] - (0.0 if common is None else common[:3, :3])
    return p, 0.5 * (own + own.T)


def run_procedure(port: CellPort, test: ComplianceTest, position: FloatArray,
                  quaternion: FloatArray, say: Say, *, run: str | None = None,
                  timeout: float = 30.0) -> list[ComplianceMarker]:
    """The test (module docstring) at the pose ``position`` (3,) m, ``quaternion`` (4,), in
    the mode the positioner is in: the markers of its steps, each also sent on
    ``/cell/compliance_test``; ``timeout`` s for the readings of a step. ProcedureError
    propagates, the rig unloaded first."""
    run = run or datetime.datetime.now(datetime.UTC).isoformat(timespec='milliseconds')
    markers: list[ComplianceMarker] = []
    try:
        for direction in test.directions:
            moved_or_raise(port.move(position, quaternion), f'move to {test.pose}')
            unit = np.asarray(DIRECTIONS[direction])
            steps = []
            for step, load in enumerate(test.loads()):
                port.apply_load(load * unit)
                port.rest(test.dwell)
                r = port.readings(test.samples, timeout)
                p, cov = averaged(r)
                marker = ComplianceMarker(
                    run, test.pose, direction, step, load, (float(p[0]), float(p[1]),
                                                            float(p[2])),
                    tuple(tuple(float(v) for v in row) for row in cov), r.start, r.end,
                    len(r.position), test.force_accuracy)
                port.mark(names.COMPLIANCE_TEST, marker.to_json())
                steps.append(marker)
            port.apply_load(np.zeros(3))
            markers += steps
            c = static_compliance(unit, [m.load for m in steps], [m.position for m in steps],
                                  [m.covariance for m in steps], test.force_accuracy)
            say(f'compliance {direction}: {len(steps) - 1} steps to {test.load:g} N at '
                f'{test.pose}: {c.compliance * 1e6:.4f} ± {c.u_compliance * 1e6:.4f} µm/N '
                f'({c.along * 1e6:+.4f} along the load, {c.nonlinearity * 1e6:.1f} µm off the '
                'line)')
        moved_or_raise(port.move(position, quaternion), f'move to {test.pose} after the test')
    finally:
        port.apply_load(np.zeros(3))
    return markers


def run_compliance_test(port: CellPort, test: ComplianceTest, position: FloatArray,
                        quaternion: FloatArray, say: Say, *, timeout: float = 30.0
                        ) -> list[ComplianceMarker]:
    """The test on the cell of ``port`` in mode ``none``, put back afterwards (ProcedureError
    when the positioner refuses it, or a step fails). The drives are stopped when anything
    but the cell's refusal or abort (an interrupt, say) ends it."""
    say(f'static compliance (ISO 9283 §10) at {test.pose}: {len(test.directions)} directions '
        f'x {test.steps} steps to {test.load:g} N, {test.samples} tracker readings each')
    with in_mode(port, CompensationMode.NONE.value, 'compliance test', say):
        markers = run_procedure(port, test, position, quaternion, say, timeout=timeout)
    say_recorded(port, names.COMPLIANCE_TEST, say)
    return markers
