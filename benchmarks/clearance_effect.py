"""Seed 000 reproduced: pose error of the uncompensated 3-UPS positioner from joint clearance
(r_a = r_b = 0.16 mm, direction angles uniform in [0, 2π)), by Monte Carlo along a 10 mm
circle at home height. Prints mean and max absolute error per axis (µm, degrees) for the
effective-length model (seed 000 eq. 9) and the exact vector model, and the error when every
clearance lies along its leg (the paper's worst case).

Run: .venv/bin/python benchmarks/clearance_effect.py [--samples 1000]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from positioning_cell import clearance
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import Mechanism


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--samples', type=int, default=1000)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    mech = Mechanism.default()
    r = mech.joint_clearance_u
    t = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    p = mech.home_position + 0.01 * np.stack([np.cos(t), np.sin(t), 0 * t], axis=1)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    rng = np.random.default_rng(args.seed)
    print(f'{args.samples} clearance draws x {len(t)} poses (10 mm circle at home height), '
          f'r_a = r_b = {r * 1e3:.2f} mm')
    print(f'{"model":18s} {"":5s} {"x um":>8s} {"y um":>8s} {"z um":>8s} '
          f'{"rx deg":>8s} {"ry deg":>8s} {"rz deg":>8s}')
    for kind in ('effective_length', 'vector'):
        t0 = time.perf_counter()
        err = np.abs(clearance.monte_carlo_pose_errors(mech, p, q, r, r, args.samples, rng,
                                                       kind)).reshape(-1, 6)
        for name, stat in (('mean', err.mean(axis=0)), ('max', err.max(axis=0))):
            print(f'{kind:18s} {name:5s} ' + ' '.join(f'{v * 1e6:8.1f}' for v in stat[:3]) + ' '
                  + ' '.join(f'{math.degrees(v):8.4f}' for v in stat[3:]))
        print(f'{"":18s} ({time.perf_counter() - t0:.1f} s)')
    cmd = kinematics.inverse(mech, p, q)
    worst = []
    for i in range(len(t)):  # every clearance along its leg: Δl = 2 (r_a + r_b) on each leg
        ph, th = cmd.phis[i], cmd.thetas[i]
        model = clearance.EffectiveLengthClearance(r, r, tuple(math.pi - ph),
                                                   tuple(math.pi - th), tuple(-ph), tuple(-th))
        att = model.attained_pose(mech, cmd.lengths[i:i + 1], cmd.thetas[i:i + 1])
        worst.append(np.abs(att.position[0] - p[i]))
    w = np.max(worst, axis=0)
    print('clearance along every leg (eq. 9): |error| max x, y, z = '
          + ', '.join(f'{v * 1e6:.1f}' for v in w) + ' um')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
