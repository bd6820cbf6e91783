"""CPU demand of one node set of the coordinated cell, at rest and while it moves, at
config/cell.yaml's rates (the baseline) and with config/coordinated.yaml's overlay (what
``run_cell --cell`` ships).

For each variant, one set of config/three_positioners.yaml (p1's: the cell_container hosting
the positioner, the leg driver and the tracker, as ``run_cell --cell`` starts it) runs alone on
a free ROS domain: homed, then a window of --seconds at rest and one while it moves back to
back 8 mm up and down along the base z axis (in the compensation mode the files give:
measured, each move corrected on the tracker). Each window gives the container's CPU seconds
per wall second (utime + stime of its threads, /proc/<pid>/stat) and the moves settled in it.
Alone, the set gets the CPU it asks for: its demand, not the share a saturated machine would
give it (three sets moving together on two cores showed only their share).

What it tells: whether three sets moving together fit this machine's cores, the budget
issue 27's shipped run (``run_cell --cell config/three_positioners.yaml``) needs beside the
coordinator, the panel simulator and the recorder.

Run: .venv/bin/python benchmarks/coordinated_sets.py [--seconds S]
Prints what it measured; exits non-zero only if a set did not come up or could not move.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from idle_cpu import cpu_seconds

from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.node_sets import start_sets
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import Processes
from positioning_cell.tools.cell_run import in_running_cell

#: The variants: a label and the parameter files, in order (the baseline first).
VARIANTS = (('cell.yaml', (config_path('cell.yaml'),)),
            ('cell.yaml + coordinated.yaml', (config_path('cell.yaml'),
                                              config_path('coordinated.yaml'))))
STROKE = 0.008       # m, the moves' length along base z
SET = 'p1'


@dataclasses.dataclass(frozen=True)
class Demand:
    """One variant's figures: cores at rest and moving, moves settled while moving."""

    rest: float
    moving: float
    moves: int
    failed: list[str]


def _cores(pid: int, seconds: float) -> float:
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)  # the measurement window itself
    return (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def measure(files: Sequence[Path], seconds: float, run_dir: Path) -> Demand:
    """One set of the three-positioner cell with ``files``: its demand (module docstring)."""
    (run_dir / 'logs').mkdir(parents=True)
    cell = cell_file.load(config_path('three_positioners.yaml'))
    one = dataclasses.replace(cell, positioners=cell.positioners[:1])
    found: list[Demand] = []

    def work(procs: Processes, client: CellClient) -> int:
        start_sets(procs, one, files, run_dir / 'params')
        done, message = client.home(120.0, namespace=SET)
        if not done:
            raise RuntimeError(f'{SET} not homed: {message}')
        port, mech = RosCellPort(client, 30.0, namespace=SET), Mechanism.default()
        pid = procs.procs[SET].pid
        rest = _cores(pid, seconds)
        stop, settled, failed = threading.Event(), [], []

        def moves() -> None:
            up = True
            while not stop.is_set():
                moved = port.move(mech.home_position + np.array([0.0, 0.0, STROKE * up]),
                                  mech.home_quaternion)
                (settled if moved[0] else failed).append(f'{moved[1]}: {moved[2]}')
                up = not up

        thread = threading.Thread(target=moves, daemon=True)
        thread.start()
        moving = _cores(pid, seconds)
        stop.set()
        thread.join(120.0)
        found.append(Demand(rest, moving, len(settled), failed))
        return 0

    status = in_running_cell(run_dir, lambda _: None, work)
    if status or not found:
        raise RuntimeError(f'the set did not come up or move (exit {status}; logs in '
                           f'{run_dir / "logs"})')
    return found[0]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='each window, s')
    args = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    print(f'one set of config/three_positioners.yaml alone, {args.seconds:g} s windows, '
          f'{cores} cores')
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, files) in enumerate(VARIANTS):
            try:
                d = measure(files, args.seconds, Path(tmp) / f'variant{k}')
            except RuntimeError as err:
                print(f'{label}: {err}')
                return 1
            figures[label] = d
            print(f'{label:30s} rest {d.rest:.3f} core, moving {d.moving:.3f} core '
                  f'({d.moves} moves settled, {len(d.failed)} not'
                  + (f': {d.failed[0]}' if d.failed else '') + ')')
    (base_label, _), (shipped_label, _) = VARIANTS
    base, shipped = figures[base_label], figures[shipped_label]
    print(f'shipped / baseline: rest {shipped.rest / base.rest:.2f}, moving '
          f'{shipped.moving / base.moving:.2f}')
    for label, d in figures.items():
        print(f'three sets moving together at {label}: {3 * d.moving:.2f} of {cores} cores, '
              f'before the coordinator, the panel simulator and the recorder')
    return 0


if __name__ == '__main__':
    sys.exit(main())
