"""``analyze_bags``: trends over many recorded cell runs (a folder tree of bags) on Dask
distributed.

    analyze_bags PATH... [--out DIR] [--config F] [--scheduler tcp://host:port] [--workers N]

Each PATH is a bag (a rosbag2 folder or an ``.mcap`` file) or a folder searched for bags
(:func:`positioning_cell.analysis.fleet.find_bags`). Every bag is one task
(:func:`positioning_cell.analysis.fleet.digest_bag`: ``analyse_bag`` with the monitor's
settings of ``config/cell.yaml`` or ``--config``, then the run's compact digest; only the
digest comes back), the largest bags first, gathered as the tasks complete, with a progress
line each. The trends over
all runs (:mod:`positioning_cell.analysis.fleet`) are written to ``--out`` (default
``fleet_trends`` in the current folder): ``trends.md``, ``trends.json`` and PNG plots
(:mod:`positioning_cell.analysis.fleet_report`).

Where the work runs: without ``--scheduler``, a ``dask.distributed.LocalCluster`` on this
machine, one single-threaded worker process per core (``--workers`` N instead; never more
than there are bags), on the loopback interface only, no dashboard; stopped at the end, on an
error and on Ctrl-C. With ``--scheduler tcp://host:port``, the workers of that running Dask
scheduler: each must have this package installed (the same version) and see the bags at the
same absolute paths as this machine.

Exit status (:mod:`positioning_cell.tools.exits`): 0 every bag analysed; 1 analysed in part (a
bag failed: its reason is printed and in the report; or a bag was damaged and analysed as far
as it was readable); 2 nothing analysed (no bag found, a path that is neither a bag nor holds
one, a bad config, every bag failed); 5 the scheduler given with ``--scheduler`` not
reachable; 130 interrupted (SIGINT, SIGTERM or SIGHUP; the cluster is stopped).
:func:`analyze_fleet` does the work; :func:`main` parses the command line.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.analysis.fleet import (
    BagFailure,
    RunDigest,
    Trends,
    digest_bag,
    find_bags,
    select_bags,
    trends,
)
from positioning_cell.analysis.fleet_report import write_plots, write_report
from positioning_cell.bag.description import parse_where
from positioning_cell.config import config_path
from positioning_cell.errors import InputError, PositioningError
from positioning_cell.tools.exits import Exit, exit_table
from positioning_cell.tools.interruption import Interrupted, interruptible

DEFAULT_OUT = Path('fleet_trends')
#: Seconds to wait for a scheduler given with --scheduler before giving up.
CONNECT_TIMEOUT = 30.0


class SchedulerUnreachableError(InputError):
    """The scheduler given with ``--scheduler`` did not answer."""


@dataclass(frozen=True)
class FleetOutput:
    """The trends, the bags that failed, and the files written: report, JSON, plots."""

    trends: Trends
    failures: tuple[BagFailure, ...]
    report: Path
    summary: Path
    plots: tuple[Path, ...]


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


#: Dask's setting of the environment a nanny gives the worker processes it spawns.
PRE_SPAWN_ENVIRON = 'distributed.nanny.pre-spawn-environ'
#: What :func:`worker_environment` leaves out of it: glibc's trim threshold, which Dask sets to
#: 64 KiB so that workers give freed memory back at once. Set at all, it also fixes glibc's
#: mmap threshold at 128 KiB: every array of that size or more is mapped afresh and its pages
#: zeroed at each use (positioning_cell.analysis.heap). A bag analysed in a worker took
#: 3.8-4.0 s with it against 2.1-2.3 s without, as in the analysing process itself
#: (2.0-2.2 s); the worker's peak RSS 217 against 238 MiB (ad hoc, one worker, four timed
#: analyses of two bags of 300 000 messages written by benchmarks/fleet.py).
TRIM_THRESHOLD = 'MALLOC_TRIM_THRESHOLD_'
#: Dask's setting of its statistical profiler on the workers, off on the local cluster unless
#: asked for: sampling every thread's stack every 10 ms cost a task about 11 % of its CPU
#: (1.86 against 1.65 s a bag) and two workers' share of two cores fell from 1.74 to 1.63
#: (benchmarks/fleet.py, one run each way). Dask's fine performance metrics stay on.
WORKER_PROFILE = 'distributed.worker.profile.enabled'


def dask_config() -> Any:
    """``dask.config`` (with distributed's defaults loaded), imported on first use."""
    _distributed()
    import dask.config

    return dask.config


def worker_environment() -> dict[str, Any]:
    """Dask's environment for the local workers (:data:`PRE_SPAWN_ENVIRON`: one BLAS and
    OpenMP thread each) without :data:`TRIM_THRESHOLD`."""
    environ = dict(dask_config().get(PRE_SPAWN_ENVIRON, {}))
    environ.pop(TRIM_THRESHOLD, None)
    return environ


def _distributed() -> Any:
    """``dask.distributed``, imported on first use (it takes seconds; its API is untyped)."""
    import dask.distributed

    return dask.distributed


@contextmanager
def _interrupts_ignored() -> Iterator[None]:
    """Meanwhile SIGINT is ignored, so that the processes started meanwhile (the workers)
    ignore it for life: a Ctrl-C of the terminal reaches every process of its group, and
    this process stops the workers itself. A Ctrl-C pressed meanwhile (while the workers
    start, seconds) is lost. Only in the main thread (elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, *,
                profile: bool = False) -> Iterator[Any]:
    """A ``dask.distributed.Client``: of the scheduler at ``scheduler`` (``tcp://host:port``),
    else of a new LocalCluster of ``workers`` (default: one per core) single-threaded worker
    processes on 127.0.0.1 without a dashboard, logging errors only, in Dask's worker
    environment but glibc's trim threshold (:func:`worker_environment`), Dask's statistical
    profiler off unless ``profile`` (:data:`WORKER_PROFILE`), started with Ctrl-C ignored
    (:func:`_interrupts_ignored`). Closed (the local cluster stopped) on leaving, however
    that happens, Ctrl-C included. InputError if the scheduler cannot be reached."""
    dd = _distributed()
    if scheduler is not None:
        try:
            client = dd.Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, ValueError) as err:
            raise SchedulerUnreachableError(f'cannot reach the Dask scheduler at {scheduler}: '
                                            f'{err}') from None
        with client:
            yield client
        return
    cluster = None
    try:
        with _interrupts_ignored(), dask_config().set(
                {PRE_SPAWN_ENVIRON: worker_environment(), WORKER_PROFILE: profile}):
            cluster = dd.LocalCluster(n_workers=workers or cores(), threads_per_worker=1,
                                      processes=True, host='127.0.0.1',
                                      dashboard_address=None, silence_logs=logging.ERROR)
        with dd.Client(cluster) as client:
            yield client
    finally:
        if cluster is not None:
            cluster.close()


def _outcome(future: Any, bag: str) -> RunDigest | BagFailure:
    """What a completed task gave: its digest or failure, or a failure saying why the task
    failed outside the analysis (a worker lost, the task cancelled, a result that did not
    arrive)."""
    try:
        if future.status == 'finished':
            result: RunDigest | BagFailure = future.result()
            return result
        err = future.exception() if future.status == 'error' else None
    except Exception as caught:
        err = caught
    return BagFailure(bag, f'{type(err).__name__}: {err}' if err is not None
                      else f'the task was {future.status}')


def bag_bytes(bag: Path) -> int:
    """The bytes a bag holds on disk: its files (a rosbag2 folder) or the file (0 for a path
    that cannot be read: its task reports why)."""
    try:
        if bag.is_dir():
            return sum(f.stat().st_size for f in bag.iterdir() if f.is_file())
        return bag.stat().st_size
    except OSError:
        return 0


def largest_first(bags: Sequence[Path]) -> list[Path]:
    """The bags by decreasing size on disk (:func:`bag_bytes`; a task's cost grows with
    it), equal sizes in the given order."""
    return sorted(bags, key=lambda b: -bag_bytes(b))


def digest_bags(client: Any, bags: Sequence[Path], settings: MonitorSettings | None = None,
                say: Callable[[str], None] = print
                ) -> tuple[list[RunDigest], list[BagFailure]]:
    """One :func:`digest_bag` task per bag on ``client``'s workers, the largest bags first
    (:func:`largest_first`); the digests and the failures, gathered as the tasks complete
    (``say`` gets a progress line each: the count, the bag, what it held or why it failed,
    the seconds since the start)."""
    start = time.perf_counter()
    order = largest_first(bags)
    # Largest first (LPT): a big bag started last would leave the other workers idle at
    # the end. Dask runs the tasks of higher priority first.
    futures = [client.submit(digest_bag, str(b), settings=settings, pure=False,
                             priority=len(order) - rank) for rank, b in enumerate(order)]
    bag_of = {f.key: str(b) for f, b in zip(futures, order, strict=True)}
    digests: list[RunDigest] = []
    failures: list[BagFailure] = []
    try:
        for done, future in enumerate(_distributed().as_completed(futures), 1):
            bag = bag_of[future.key]
            result = _outcome(future, bag)
            future.release()
            head = f'[{done}/{len(bags)}] {bag}'
            took = f'{time.perf_counter() - start:.1f} s'
            if isinstance(result, BagFailure):
                failures.append(result)
                say(f'{head}: FAILED: {result.reason} ({took})')
            else:
                digests.append(result)
                damaged = f', {len(result.problems)} problem(s)' if result.problems else ''
                say(f'{head}: {len(result.modes)} mode(s), {len(result.poses)} mode × pose'
                    f'{damaged} ({took})')
    finally:
        client.cancel(futures)  # nothing left running when interrupted
    return digests, failures


def analyze_fleet(paths: Sequence[str | Path], out_dir: str | Path = DEFAULT_OUT,
                  config: str | Path | None = None, scheduler: str | None = None,
                  workers: int | None = None, say: Callable[[str], None] = print,
                  where: Mapping[str, str] | None = None) -> FleetOutput:
    """Find the bags under ``paths`` (only those whose description has every ``key: value``
    of ``where``: :func:`select_bags`), digest each on Dask (:func:`dask_client`), and write
    the trend report, JSON and plots into ``out_dir``. Raises PositioningError (InputError,
    ConfigError) when nothing can be analysed: no bag (none selected), a bad config, no
    scheduler."""
    found = find_bags(paths)
    bags = select_bags(found, where or {})
    if not bags:
        terms = ', '.join(f'{k}={v}' for k, v in (where or {}).items())
        raise InputError(f'none of the {len(found)} bag(s) found has {terms} in its '
                         'description')
    if len(bags) < len(found):
        say(f'analyze_bags: {len(bags)} of {len(found)} bag(s) selected by their description')
    settings = MonitorSettings.from_file(config or config_path('cell.yaml'))
    local = min(workers or cores(), len(bags))
    on = (f'the scheduler at {scheduler}' if scheduler is not None else
          f'{local} local worker process(es)')
    say(f'analyze_bags: {len(bags)} bag(s) on {on}')
    with dask_client(scheduler, local) as client:
        digests, failures = digest_bags(client, bags, settings, say)
    return report_fleet(digests, failures, out_dir)


def report_fleet(digests: Sequence[RunDigest], failures: Sequence[BagFailure],
                 out_dir: str | Path) -> FleetOutput:
    """The part of :func:`analyze_fleet` after the workers, in this process: the trends of
    the digests, and the plots, report and JSON written into ``out_dir``."""
    result = trends(digests)
    out = Path(out_dir)
    plots = write_plots(result, out)
    report, summary = write_report(result, out, failures, plots)
    return FleetOutput(result, tuple(failures), report, summary, tuple(plots))


def describe(output: FleetOutput) -> str:
    """What to print at the end: the counts and the files."""
    t = output.trends
    lines = [f'analyze_bags: {len(t.runs)} run(s) analysed, {len(output.failures)} failed; '
             f'{len(t.series)} mode × pose series, {len(t.epochs)} calibration epoch(s), '
             f'{t.registrations.time.size} registration(s)',
             f'report:  {output.report}', f'summary: {output.summary}',
             'plots:   ' + (', '.join(str(p) for p in output.plots) or 'none')]
    return '\n'.join(lines) + '\n'


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'{text}: expected at least 1')
    return value


def main(argv: Sequence[str] | None = None) -> int:
    """Command line; see the module docstring for the exit status."""
    parser = argparse.ArgumentParser(
        prog='analyze_bags', description='Trends over many recorded positioning cell runs: '
        'ISO 9283 AP/RP per pose and mode over time, drift since each calibration, the '
        'tracker\'s registration residuals; on Dask distributed.',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('paths', nargs='+', type=Path, metavar='PATH',
                        help='a bag (rosbag2 folder or .mcap file) or a folder of bags')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT,
                        help=f'output folder (default: ./{DEFAULT_OUT})')
    parser.add_argument('--config', type=Path, help='ROS 2 parameter file with the monitor\'s '
                        'settings (default: the shipped config/cell.yaml)')
    where = parser.add_mutually_exclusive_group()
    where.add_argument('--scheduler', metavar='tcp://host:port',
                       help='a running Dask scheduler whose workers do the work (they need '
                            'this package and the bags at the same paths)')
    where.add_argument('--workers', type=_positive,
                       help='local worker processes (default: one per core)')
    parser.add_argument('--where', action='append', default=[], metavar='KEY=VALUE',
                        help='only the bags whose description has this value (repeatable; '
                             'keys such as kind, program, mechanism_fingerprint, '
                             'calibration_file, calibration_sha256: analyze_bag\'s report '
                             'lists a bag\'s keys)')
    args = parser.parse_args(argv)
    try:
        selection = parse_where(args.where)
    except ValueError as err:
        parser.error(str(err))

    def say(line: str) -> None:
        print(line, flush=True)

    try:
        with interruptible():
            output = analyze_fleet(args.paths, args.out, args.config, args.scheduler,
                                   args.workers, say, selection)
    except SchedulerUnreachableError as err:
        print(f'analyze_bags: error: {err}', file=sys.stderr)
        return Exit.NOT_THERE
    except PositioningError as err:
        print(f'analyze_bags: error: {err}', file=sys.stderr)
        return Exit.USAGE
    except Interrupted as signal_name:
        print(f'analyze_bags: interrupted ({signal_name}); the workers are stopped',
              file=sys.stderr)
        return Exit.INTERRUPTED
    sys.stdout.write(describe(output))
    for failure in output.failures:
        print(f'analyze_bags: failed: {failure.bag}: {failure.reason}', file=sys.stderr)
    if not output.trends.runs:
        print('analyze_bags: no bag could be analysed', file=sys.stderr)
        return Exit.USAGE
    if output.failures or any(r.problems for r in output.trends.runs):
        return Exit.NOT_ACHIEVED
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
