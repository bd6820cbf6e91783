"""Where the test suite's time goes (issue 24: ``make test`` <= 4 min on 2 cores): CPU per test
module, of the test process and of the processes it started and reaped.

Runs one tier of ``make test`` as the Makefile does (the node tier: ``-n 3 --dist loadscope`` on
the Makefile's NODE_TIER expression; ``--timing``: the timing tier, serially; ``--library``: the
library tier, LIBRARY_TIER in two workers, here alone and at the normal priority, where make
test runs it beside the timing tier at idle priority), with this file loaded as a pytest plugin
in every worker: around each test, the worker's ``getrusage(RUSAGE_SELF)`` and
``getrusage(RUSAGE_CHILDREN)`` (the nodes and tools a test starts count once they are reaped,
which every test's ProcessGroup does at its end; a module fixture's cell falls on the module's
last test). Prints the tier's wall time and CPU (this process's children: the workers and all
they started), the floor that CPU sets on the cores given (CPU / cores), each worker's busy time
and last module (their spread: what the modules' order leaves idle at the end), and each
module's CPU (test process, started processes) and wall time, costliest first.

Further arguments go to pytest (e.g. a module). Run from the checkout with the venv's python
and make test's environment, e.g.
``env $(RUN_ENV) .venv/bin/python benchmarks/suite_cpu.py`` (the Makefile's RUN_ENV).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Where the plugin writes each worker's rows (set by main for the pytest run it starts).
OUT_ENV = 'SUITE_CPU_OUT'
_rows: list[tuple[str, float, float, float]] = []


def _cpu(who: int) -> float:
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """One row per test: its node id, CPU s of the test process, of reaped children, wall s."""
    own, kids, wall = (_cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN),
                       time.monotonic())
    yield
    _rows.append((item.nodeid, _cpu(resource.RUSAGE_SELF) - own,
                  _cpu(resource.RUSAGE_CHILDREN) - kids, time.monotonic() - wall))


def pytest_sessionfinish(session: pytest.Session) -> None:
    out = os.environ.get(OUT_ENV)
    if out:
        worker = os.environ.get('PYTEST_XDIST_WORKER', 'main')
        (Path(out) / f'{worker}.json').write_text(json.dumps(_rows))


def per_module(rows: list[Any]) -> dict[str, list[float]]:
    """Module file name → [test-process CPU s, started-processes CPU s, wall s, tests]."""
    modules: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0, 0.0, 0.0])
    for node_id, own, kids, wall in rows:
        m = modules[node_id.split('::')[0].rsplit('/', 1)[-1]]
        m[0] += own
        m[1] += kids
        m[2] += wall
        m[3] += 1
    return modules


def report_workers(by_worker: dict[str, list[Any]]) -> None:
    """Each worker's busy time (its tests' wall times summed, set-up and teardown included) and
    the module it ran last: the tier's wall time is its busiest worker's, so the spread is what
    the order of the modules (conftest.LONGEST_FIRST) leaves idle at the end."""
    busy = {worker: sum(row[3] for row in rows) for worker, rows in by_worker.items()
            if rows}  # (xdist's controller ran no test)
    for worker in sorted(busy):
        last = by_worker[worker][-1][0].split('::')[0].rsplit('/', 1)[-1]
        print(f'worker {worker}: busy {busy[worker]:.0f} s, last module {last}')
    if len(busy) > 1:
        spread = max(busy.values()) - min(busy.values())
        print(f'spread of the workers\' busy times: {spread:.0f} s')


def makefile_variable(name: str) -> str:
    """The value of ``name := value`` in the checkout's Makefile (a tier's marker expression,
    declared there once)."""
    for line in (ROOT / 'Makefile').read_text().splitlines():
        key, sep, value = line.partition(':=')
        if sep and key.strip() == name:
            return value.strip()
    raise SystemExit(f'no {name} := ... in the Makefile')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    tiers = parser.add_mutually_exclusive_group()
    tiers.add_argument('--timing', action='store_true', help='the timing tier (serially)')
    tiers.add_argument('--library', action='store_true', help='the library tier')
    parser.add_argument('--workers', type=int, help='the tier\'s workers (default: the '
                        'Makefile\'s, 3 for the node tier, 2 for the library tier)')
    parser.add_argument('--cores', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--top', type=int, default=15, help='modules listed')
    args, more = parser.parse_known_args()  # the rest goes to pytest (modules, -k ...)
    if args.timing:
        tier = ['-m', 'timing']
    else:
        workers = args.workers or (2 if args.library else 3)
        expression = makefile_variable('LIBRARY_TIER' if args.library else 'NODE_TIER')
        tier = ['-n', str(workers), '--dist', 'loadscope', '-m', expression]
    with tempfile.TemporaryDirectory() as out:
        # COLUMNS: -ra's summary line keeps each failure's reason (cut to the width, which
        # pytest takes as 80 without a terminal: a long test id alone fills it)
        env = {**os.environ, OUT_ENV: out, 'COLUMNS': '400',
               'PYTHONPATH': os.pathsep.join(filter(None, [str(ROOT / 'benchmarks'),
                                                           os.environ.get('PYTHONPATH')]))}
        before, start = _cpu(resource.RUSAGE_CHILDREN), time.monotonic()
        command = [sys.executable, '-m', 'pytest', *tier, '-q', '-p', 'suite_cpu', *more]
        ran = subprocess.run(command, cwd=ROOT, env=env, check=False, capture_output=True,
                             text=True)
        wall, cpu = time.monotonic() - start, _cpu(resource.RUSAGE_CHILDREN) - before
        by_worker = {f.stem: json.loads(f.read_text()) for f in Path(out).glob('*.json')}
        rows = [row for worker_rows in by_worker.values() for row in worker_rows]
    said = ran.stdout.strip().splitlines()
    print(said[-1] if said else ran.stderr[-2000:])
    for line in said:  # -ra's summary: which tests failed or errored, and why
        if line.startswith(('FAILED ', 'ERROR ')):
            print(line)
    modules = per_module(rows)
    own, kids = sum(m[0] for m in modules.values()), sum(m[1] for m in modules.values())
    print(f'tier: {wall:.0f} s wall, {cpu:.0f} s CPU ({cpu / wall:.2f} cores busy); '
          f'CPU / {args.cores} cores = {cpu / args.cores:.0f} s, the floor on its wall time')
    print(f'per test, summed: {own + kids:.0f} s CPU: {own:.0f} in the test processes, '
          f'{kids:.0f} in the processes they started')
    report_workers(by_worker)
    print(f'{"module":<34} {"CPU s":>7} {"own":>7} {"started":>8} {"wall s":>7} {"n":>5}')
    for name, (m_own, m_kids, m_wall, n) in sorted(
            modules.items(), key=lambda kv: -(kv[1][0] + kv[1][1]))[:args.top]:
        print(f'{name:<34} {m_own + m_kids:7.1f} {m_own:7.1f} {m_kids:8.1f} {m_wall:7.1f} '
              f'{int(n):5d}')
    return ran.returncode


if __name__ == '__main__':
    sys.exit(main())
