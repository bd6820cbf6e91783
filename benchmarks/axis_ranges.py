"""Live axis ranges (issue 26, item 6): the time of all twelve bounds of one pose.

Measures, on one core, for poses drawn in the workspace (a user CS moved and turned from the
machine CS, an object CS with its pivot off the platform's centre, the default factory box and
a wide one where the mechanism's own limits bind):
- :meth:`positioning_cell.limits.axis_ranges.RangeModel.ranges` per pose: median and p95 of
  wall time, the model taken from :meth:`RangeModel.cached` (the positioner's limits and
  coordinate systems change seldom), and apart the time to build a model anew;
- the same searches as the positioner runs them, through its range worker (a process of its
  own, :mod:`positioning_cell.limits.range_worker`): the round trip per pose, the pipe and
  pickles included, median and p95, once the worker is ready;
- a baseline in the same run: one single-pose validity check as the positioner makes it
  (:func:`positioning_cell.limits.validity.factory_check` and the machine box on scipy's Euler
  angles), median.

Run: ``.venv/bin/python benchmarks/axis_ranges.py [poses]``. Prints what it measured against
the target (all twelve bounds in <= 2 ms); exits non-zero only if results are wrong, never on
speed. The machine is shared: the median is the least disturbed figure.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time

import numpy as np

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform, pose6_from_pq
from positioning_cell.limits import axis_ranges
from positioning_cell.limits.boxes import BoxLimits, LimitLayers, base_pq_of_machine_pose6
from positioning_cell.limits.range_worker import RangeWorker
from positioning_cell.limits.validity import factory_check
from positioning_cell.polling import wait_until

MECH = Mechanism.default()
TARGET_S = 2e-3
WIDE = BoxLimits((-0.1, -0.1, -0.1, -1.2, -1.2, -1.2), (0.1, 0.1, 0.1, 1.2, 1.2, 1.2))


def main() -> int:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    with contextlib.suppress(AttributeError, OSError):  # one core
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    axis_ranges.warm_up()
    rng = np.random.default_rng(0)
    times: list[float] = []
    builds: list[float] = []
    trips: list[float] = []
    worker = RangeWorker(answer_timeout=5.0)
    wait_until(lambda: worker.ranges(axis_ranges.RangeModel.cached(
        MECH, LimitLayers.for_mechanism(MECH), CoordinateSystems()), np.zeros(6)).valid, 120.0,
        'the range worker')
    valid = 0
    for layers_name, layers in (('default factory box', LimitLayers.for_mechanism(MECH)),
                                ('wide factory box', LimitLayers.of(WIDE))):
        for _ in range(n):
            systems = CoordinateSystems(
                Transform.from_pose6(rng.uniform(-1, 1, 6) * [0.01, 0.01, 0.01, 0.1, 0.1, 0.1]),
                Transform.from_pose6(np.r_[rng.uniform(-1, 1, 3) * 0.02, 0.0, 0.0, 0.0]))
            start = rng.uniform(-1, 1, 6) * [0.015, 0.015, 0.01, 0.15, 0.15, 0.15]
            t0 = time.perf_counter()
            axis_ranges.RangeModel.of(MECH, layers, systems)
            builds.append(time.perf_counter() - t0)
            model = axis_ranges.RangeModel.cached(MECH, layers, systems)
            t0 = time.perf_counter()
            found = axis_ranges.RangeModel.cached(MECH, layers, systems).ranges(start)
            elapsed = time.perf_counter() - t0
            t0 = time.perf_counter()
            through = worker.ranges(model, start)
            trip = time.perf_counter() - t0
            if found != model.ranges(start) or through != found:
                print('WRONG: two searches of one pose differ (here, or here and the worker)')
                return 1
            if found.valid:
                valid += 1
                times.append(elapsed)
                trips.append(trip)
                if not all(r.low <= start[k] <= r.high for k, r in enumerate(found.ranges)):
                    print(f'WRONG: a range of {start} does not hold the pose: {found}')
                    return 1
        print(f'{layers_name}: poses drawn {n}')
    layers = LimitLayers.for_mechanism(MECH)
    pose = np.zeros((1, 6))
    baseline = []
    for _ in range(200):
        t0 = time.perf_counter()
        p, q = base_pq_of_machine_pose6(MECH, pose)
        factory_check(MECH, p, q).merged(layers.check(pose6_from_pq(p - MECH.home_position, q)))
        baseline.append(time.perf_counter() - t0)
    median, p95 = np.median(times), np.percentile(times, 95)
    check = float(np.median(baseline))
    print(f'axis ranges, all twelve bounds, {valid} valid poses (one core):')
    print(f'  median {median * 1e3:.3f} ms, p95 {p95 * 1e3:.3f} ms, max '
          f'{max(times) * 1e3:.3f} ms (target <= {TARGET_S * 1e3:.0f} ms: '
          f'{"met" if p95 <= TARGET_S else "NOT met"} at p95)')
    print(f'  through the range worker (the positioner\'s path, its own process): median '
          f'{np.median(trips) * 1e3:.3f} ms, p95 {np.percentile(trips, 95) * 1e3:.3f} ms '
          f'(target <= {TARGET_S * 1e3:.0f} ms: '
          f'{"met" if np.percentile(trips, 95) <= TARGET_S else "NOT met"} at p95)')
    worker.close()
    print(f'  building a model anew (limits or CS changed): median '
          f'{np.median(builds) * 1e3:.3f} ms')
    print(f'baseline, one single-pose validity check (numpy): median {check * 1e3:.3f} ms; '
          f'the twelve bounds take {median / check:.1f} of them')
    return 0


if __name__ == '__main__':
    sys.exit(main())
