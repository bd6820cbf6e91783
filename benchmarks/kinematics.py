"""Kinematics throughput: batched IK and FK (N = 100 000), single-pose latency, and the ratio
against a per-pose scipy.optimize.least_squares FK measured in the same run.

Run: make bench, or .venv/bin/python benchmarks/kinematics.py [--n 100000]
Targets (issue 2): batched FK >= 1 000 000 poses/s on one core and >= 2 000x the per-pose
baseline. Prints what it measured; exits non-zero only if results are wrong, never on speed.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

import numpy as np
from scipy.spatial.transform import Rotation

from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.testing.reference_kinematics import reference_forward

MECH = Mechanism.default()


def workspace_poses(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Poses in a box around home (±15 mm, ±12 mm in z, rotations up to ~0.2 rad)."""
    p = MECH.home_position + rng.uniform(-1, 1, (n, 3)) * [0.015, 0.015, 0.012]
    q = Rotation.from_rotvec(rng.uniform(-1, 1, (n, 3)) * 0.12).as_quat()
    return p, q


def best_of(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    """Best wall time of ``repeats`` calls (s): the least disturbed by the shared VM."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--n', type=int, default=100_000)
    parser.add_argument('--baseline-poses', type=int, default=200)
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):  # one core
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    rng = np.random.default_rng(0)
    p, q = workspace_poses(args.n, rng)

    ik_time = best_of(lambda: kinematics.inverse(MECH, p, q), 5)
    joints = kinematics.inverse(MECH, p, q)
    fk_time = best_of(lambda: kinematics.forward(MECH, joints.lengths, joints.thetas), 5)
    fk = kinematics.forward(MECH, joints.lengths, joints.thetas)
    pos_err = float(np.abs(fk.position - p).max())
    rot_err = float((Rotation.from_quat(fk.quaternion).inv() * Rotation.from_quat(q))
                    .magnitude().max())
    warm_time = best_of(lambda: kinematics.forward(MECH, joints.lengths, joints.thetas,
                                                   joints.phis + 1e-4), 5)

    one_l, one_t = joints.lengths[:1], joints.thetas[:1]
    single = best_of(lambda: [kinematics.forward(MECH, one_l, one_t) for _ in range(200)], 3)
    single_ik = best_of(lambda: [kinematics.inverse(MECH, p[0], q[0]) for _ in range(200)], 3)

    m = args.baseline_poses
    t0 = time.perf_counter()
    sols = [reference_forward(MECH, joints.lengths[i], joints.thetas[i]) for i in range(m)]
    base_time = (time.perf_counter() - t0) / m
    base_err = max(float(np.abs(s[0] - p[i]).max()) for i, s in enumerate(sols))

    fk_rate = args.n / fk_time
    print(f'poses: N = {args.n} in the workspace box; one core; best of 5 runs')
    print(f'batched IK      : {args.n / ik_time:12,.0f} poses/s')
    print(f'batched FK      : {fk_rate:12,.0f} poses/s (from home; all converged: '
          f'{bool(fk.converged.all())}; max error {pos_err:.1e} m, {rot_err:.1e} rad)')
    print(f'batched FK warm : {args.n / warm_time:12,.0f} poses/s (started from the previous '
          f'solution, as along a trajectory)')
    print(f'single-pose FK  : {single / 200 * 1e6:10.1f} us   single-pose IK: '
          f'{single_ik / 200 * 1e6:.1f} us')
    print(f'baseline FK     : {1 / base_time:12,.0f} poses/s (scipy least_squares per pose, '
          f'{m} poses, max error {base_err:.1e} m)')
    print(f'ratio batched FK / baseline: {fk_rate * base_time:,.0f}x   '
          f'(targets: >= 1,000,000 poses/s and >= 2,000x)')
    ok = fk.converged.all() and pos_err <= 1e-12 and rot_err <= 1e-12
    return 0 if ok else 1


if __name__ == '__main__':
    raise SystemExit(main())
