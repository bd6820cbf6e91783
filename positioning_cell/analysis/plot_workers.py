"""The plots of an analysis drawn in worker processes while the analysis goes on (issue 24).

Drawing the four plots costs ~1.5-2 s of matplotlib (Python, per axes, tick and text: not the
bag's length) and importing matplotlib ~0.6 s more, as much as the rest of a million-message
analysis. :class:`PlotWorkers` forks its workers when it is made, before the bag is read: they
import matplotlib and draw a small figure (fonts loaded, caches filled) on the otherwise idle
second core while the bag is read and replayed. Once the replay is done (the plots need neither
the error budget nor the report) :meth:`PlotWorkers.start` hands each worker its share of the
plots, heaviest first, and the error budget's pass and the report go on here meanwhile;
:meth:`PlotWorkers.paths` waits for the files.

The workers are forked (they inherit the imported modules; nothing else is started: a spawned
interpreter would import numpy and the package again) and run at a lower priority
(:data:`WORKER_NICE`): on two cores, two workers and the analysing process would otherwise
share them three ways, and the analysis, which the plots wait for, would slow by a third. An
analysis that fails ends its workers at once, warmed up or not. A
process with other threads running (e.g. ``run_cell``, whose ROS client has its own) is not
forked: there, and with a single worker or core, the plots are drawn here, one after the
other, in :meth:`PlotWorkers.paths`.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from pathlib import Path
from types import TracebackType

from positioning_cell.accuracy.monitor import Monitor
from positioning_cell.analysis.plots import (
    ACCURACY_MAP,
    AXIS_ERRORS,
    CLUSTERS,
    ERROR_DISTRIBUTION,
    ERROR_OVER_TIME,
    draw_plots,
    plot_names,
)
from positioning_cell.analysis.summary import RunAnalysis
from positioning_cell.plotting import warm_up

#: The plots from the costliest to draw to the cheapest (measured on a tiled `make run` bag:
#: the clusters have two axes per pose, the axis errors two per mode; the accuracy map six
#: axes, drawn instead of those two).
COST_ORDER = (CLUSTERS, AXIS_ERRORS, ACCURACY_MAP, ERROR_OVER_TIME, ERROR_DISTRIBUTION)


def shares(names: list[str], workers: int) -> list[list[str]]:
    """``names`` dealt to ``workers`` in :data:`COST_ORDER`, back and forth (the costliest and
    the cheapest together), without the empty shares."""
    ordered = sorted(names, key=COST_ORDER.index)
    dealt: list[list[str]] = [[] for _ in range(workers)]
    for i, name in enumerate(ordered):
        turn, k = divmod(i, workers)
        dealt[k if turn % 2 == 0 else workers - 1 - k].append(name)
    return [share for share in dealt if share]


def for_plots(analysis: RunAnalysis) -> RunAnalysis:
    """``analysis`` without what no plot draws (the monitor's state, the true visits and
    modes, the program steps): what is sent to each worker, pickled; on a `make run` bag tiled
    to 4 M messages 1.8 MB instead of 4.3 MB."""
    replay = replace(analysis.replay, monitor=Monitor(analysis.settings), truth_visits=(),
                     program=())
    return replace(analysis, replay=replay, truth_modes=())


def can_fork(workers: int) -> bool:
    """Whether to draw in forked workers: more than one worker and core, and no other thread
    in this process (a fork copies a lock held by another thread held for ever)."""
    return (workers > 1 and (os.cpu_count() or 1) > 1 and threading.active_count() == 1
            and 'fork' in multiprocessing.get_all_start_methods())


#: The workers' nice value: below the analysing process, which the plots wait for, so that it
#: keeps its core (on the 2-core VM, a 1 M-message `make run` bag, fresh processes
#: alternating: analyze with the plots 1.73-1.92 s at 19 against 1.78-2.15 s at 0), but not the
#: lowest: at 19 a busy machine starves them (CFS gives a nice-19 process 1.5 % of a nice-0
#: one's share; test_plot_workers's plots took 129 s under three busy loops on two cores, 8.8 s
#: at 5, which still leaves the analysis three quarters of a core it shares with a worker).
WORKER_NICE = 5


def start_worker() -> None:
    """A worker's start: a lower priority (:data:`WORKER_NICE`), then matplotlib warmed up
    (:func:`positioning_cell.plotting.warm_up`)."""
    os.nice(WORKER_NICE)
    warm_up()


#: The longest wait (s) for the workers' plots; past it they are ended and the plots drawn
#: in this process (a few seconds is usual: nothing hangs on a stuck worker).
PLOT_TIMEOUT = 120.0


class PlotWorkers:
    """Workers that draw the plots of one analysis (module docstring); a context manager
    (its exit ends the workers). ``workers``: processes (default 2: the VMs' cores)."""

    def __init__(self, workers: int = 2) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._futures: list[Future[list[Path]]] = []
        self._pending: tuple[RunAnalysis, Path, list[str]] | None = None
        self._workers = workers
        if can_fork(workers):
            self._pool = ProcessPoolExecutor(workers, multiprocessing.get_context('fork'),
                                             initializer=start_worker)
            self._pool.submit(os.getpid)  # forks them now: they warm up during the read

    @property
    def forked(self) -> bool:
        """Whether worker processes draw (else :meth:`paths` draws here)."""
        return self._pool is not None

    def start(self, analysis: RunAnalysis, out_dir: Path) -> list[Path]:
        """Start drawing the plots of ``analysis`` into ``out_dir`` (created); the paths the
        plots will have (:func:`~positioning_cell.analysis.plots.plot_names`)."""
        out_dir.mkdir(parents=True, exist_ok=True)
        names = plot_names(analysis)
        if self._pool is None:
            self._pending = (analysis, out_dir, names)
        else:
            sent = for_plots(analysis)
            self._futures = [self._pool.submit(draw_plots, sent, out_dir, share)
                             for share in shares(names, self._workers)]
            self._pending = (analysis, out_dir, names)
        return [out_dir / name for name in names]

    def paths(self) -> list[Path]:
        """Wait for the plots :meth:`start` asked for; their paths. A worker's error is
        raised here; workers that could not start (their pool broken) leave the plots to be
        drawn here."""
        if self._pending is None:
            raise RuntimeError('PlotWorkers.paths() before start()')
        analysis, out_dir, names = self._pending
        if self._pool is not None:
            try:
                drawn = {p.name: p for f in self._futures
                         for p in f.result(timeout=PLOT_TIMEOUT)}
                return [drawn[name] for name in names]
            except BrokenProcessPool:
                pass
            except FutureTimeout:  # a worker stuck (e.g. a lock copied by the fork): end it
                self._end_workers()
        return draw_plots(analysis, out_dir, names)

    def _end_workers(self) -> None:
        """Kill the workers now and forget the pool (its plots are drawn here). SIGKILL, not
        SIGTERM: a forked worker has its parent's signal handlers, and one signalled just
        after the fork, before multiprocessing's child code is entered, unwinds as a copy of
        its parent (a SIGTERM handler raising KeyboardInterrupt, as pytest's conftest has
        it, made a copy of a pytest-xdist worker end the session in its name: the CI saw
        "worker finished" mid-test, an analysis of an empty bag failing at once after the
        fork). A worker holds nothing to save."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        for process in list(getattr(pool, '_processes', {}).values()):
            process.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> PlotWorkers:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if kind is not None:  # nothing to draw: the workers (maybe still warming up) end now
            self._end_workers()
        elif self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
