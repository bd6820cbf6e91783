"""Clean stops of every node executable: 30 stops per node, SIGINT and SIGTERM alternating,
spread over the start (from the moment the entry point's handler is in, while the modules load,
while rclpy comes up and the node is built, to after it runs).

Each trial starts the six executables together on a free ROS domain (the recorder into a
temporary bag, the player looping a synthetic bag) and signals each one ``k * --step`` s after
it catches SIGTERM (k = 0 .. trials-1; positioning_cell.testing.stops). For each node: how many
stops were clean (exit 0, nothing of CRASH_SIGNS printed) and the median and largest time from
the signal to the exit. The baseline, from the same trials: a bare rclpy node (``rclpy.spin``
with rclpy's defaults), signalled the same way once rclpy has installed its handlers.

Run: .venv/bin/python benchmarks/shutdown.py [--trials 30] [--step 0.15]
Targets: every stop of the package's nodes clean (issue 11), none taking more than 2 s
(issue 21: "SIGINT/SIGTERM stop every node within 2 s whatever it is doing"). Exits 1 if one
is not met.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import sys
import tempfile
from pathlib import Path

from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.processes import cell_environment
from positioning_cell.testing.stops import Stop, stop_after, stop_commands

BARE = 'bare_rclpy_node'
#: Longest stop of a node of the package (issue 21), s.
STOP_TARGET_S = 2.0
BARE_NODE = ('import rclpy, rclpy.node\n'
             'rclpy.init()\n'
             'rclpy.spin(rclpy.node.Node("bare_node"))\n')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--trials', type=int, default=30)
    parser.add_argument('--step', type=float, default=0.15,
                        help='s between the stop moments of successive trials')
    args = parser.parse_args()
    results: dict[str, list[Stop]] = {}
    with tempfile.TemporaryDirectory(prefix='shutdown_bench_') as tmp_dir:
        for k in range(args.trials):
            sig = signal.SIGINT if k % 2 == 0 else signal.SIGTERM
            run = Path(tmp_dir) / f'trial{k}'
            commands = {**stop_commands(run), BARE: [sys.executable, '-c', BARE_NODE]}
            with free_domain() as domain:
                for stop in stop_after(commands, cell_environment(domain), run, sig,
                                       k * args.step):
                    results.setdefault(stop.label, []).append(stop)
            print(f'trial {k + 1}/{args.trials}: {sig.name} {k * args.step:.2f} s into the '
                  'start', flush=True)
    print(f'\n{"executable":24s} {"clean":>7s} {"median s":>9s} {"max s":>7s}  not clean')
    all_clean = in_time = True
    for label, stops in results.items():
        clean = sum(s.clean for s in stops)
        took = [s.seconds for s in stops]
        bad = [f'trial {i + 1}: {s.problem}' for i, s in enumerate(stops) if not s.clean]
        print(f'{label:24s} {clean:3d}/{len(stops):<3d} {statistics.median(took):9.3f} '
              f'{max(took):7.3f}  {"; ".join(bad[:3])}{" ..." if len(bad) > 3 else ""}')
        if label != BARE:
            all_clean &= clean == len(stops)
            in_time &= max(took) <= STOP_TARGET_S
    for stops in results.values():
        for i, s in enumerate(stops):
            if s.stacks:  # a stop still running NATIVE_STACKS_AFTER_S after its signal
                print(f'\ntrial {i + 1}, {s.describe()}')
    print(f'\ntargets: every stop of the package\'s nodes clean: '
          f'{"met" if all_clean else "NOT met"}; none longer than {STOP_TARGET_S:g} s: '
          f'{"met" if in_time else "NOT met"} ({BARE}: the baseline, rclpy defaults)')
    return 0 if all_clean and in_time else 1


if __name__ == '__main__':
    raise SystemExit(main())
