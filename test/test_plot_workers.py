"""The plots drawn in worker processes (positioning_cell.analysis.plot_workers): the same
figures as drawn in the process, the shares of the plots, the serial fallback when the process
has other threads; the log axes' minor ticks (positioning_cell.plotting.log_scale)."""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from matplotlib.image import imread
from numpy.testing import assert_allclose

from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.plot_workers import (
    COST_ORDER,
    WORKER_NICE,
    PlotWorkers,
    can_fork,
    shares,
)
from positioning_cell.analysis.plots import plot_names, write_plots
from positioning_cell.analysis.summary import RunAnalysis
from positioning_cell.config import config_path
from positioning_cell.plotting import figure, log_scale
from positioning_cell.polling import wait_until
from positioning_cell.ros.processes import OWN_PROCESS_GROUP
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.192]])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))


@pytest.fixture(scope='module')
def analysis(tmp_path_factory: pytest.TempPathFactory) -> RunAnalysis:
    path = tmp_path_factory.mktemp('bags') / 'run'
    write_run_bag(path, synthetic_run(POSITIONS, QUATERNIONS, cycles=2, dwell_time=1.5, seed=3))
    return analyse_bag(path, MonitorSettings.from_file(config_path('cell.yaml')))


def _same_images(a: list[Path], b: list[Path]) -> None:
    assert [p.name for p in a] == [p.name for p in b]
    for x, y in zip(a, b, strict=True):
        assert x != y
        assert_allclose(imread(x), imread(y), atol=1e-6, err_msg=x.name)


DRAW_IN_WORKERS = """
import pickle, sys
from pathlib import Path
from positioning_cell.analysis.plot_workers import PlotWorkers
analysis = pickle.loads(Path(sys.argv[1]).read_bytes())
with PlotWorkers() as workers:
    assert workers.forked
    planned = workers.start(analysis, Path(sys.argv[2]))
    drawn = workers.paths()
assert planned == drawn
print('\\n'.join(str(p) for p in drawn))
"""


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason='one core: the plots are drawn serially')
def test_the_workers_draw_the_plots_the_process_would(analysis: RunAnalysis,
                                                      tmp_path: Path) -> None:
    # In a fresh interpreter: pytest's process has other threads (a plugin's server), so it
    # draws serially.
    source = tmp_path / 'analysis.pickle'
    source.write_bytes(pickle.dumps(analysis))
    done = subprocess.run([sys.executable, '-c', DRAW_IN_WORKERS, str(source),
                           str(tmp_path / 'workers')], check=False, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    drawn = [Path(line) for line in done.stdout.split()]
    assert drawn == [tmp_path / 'workers' / n for n in plot_names(analysis)]
    assert len(drawn) == 4
    _same_images(write_plots(analysis, tmp_path / 'here'), drawn)


def test_with_another_thread_running_the_plots_are_drawn_here(analysis: RunAnalysis,
                                                              tmp_path: Path) -> None:
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not can_fork(2)
        with PlotWorkers() as workers:
            assert not workers.forked
            planned = workers.start(analysis, tmp_path / 'out')
            assert not any(p.exists() for p in planned)  # drawn only when asked for
            drawn = workers.paths()
    finally:
        stop.set()
        other.join()
    assert drawn == planned
    _same_images(write_plots(analysis, tmp_path / 'here'), drawn)


def test_a_worker_starts_at_a_lower_priority_matplotlib_warm() -> None:
    code = ('import os, sys; from positioning_cell.analysis.plot_workers import start_worker; '
            'start_worker(); print(os.nice(0), "matplotlib" in sys.modules)')
    done = subprocess.run([sys.executable, '-c', code], check=False, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [str(WORKER_NICE), 'True']
    # below the analysis, never starved: at 19 a busy machine left the workers ~1 % of a core
    # (a test's plots took 129 s under three busy loops on two cores; 8.8 s at 5)
    assert 0 < WORKER_NICE <= 10


#: A fresh interpreter (one thread: the workers are forked) whose workers never end their
#: warm-up, and whose analysis fails: it prints the workers' pids once out of the ``with``.
_FAILED_ANALYSIS = """
import threading
from positioning_cell.analysis import plot_workers
plot_workers.warm_up = lambda: threading.Event().wait()
workers = plot_workers.PlotWorkers()
assert workers.forked
pids = list(workers._pool._processes)
try:
    with workers:
        raise ValueError('the bag is refused')
except ValueError:
    print(*pids)
"""


def test_an_analysis_that_fails_ends_its_workers_at_once() -> None:
    """A bag refused (an error inside the ``with``) ends the workers then and there, even
    ones still warming up: here a warm-up that never ends, which a shutdown waiting for the
    workers would wait on for ever (the interpreter would not exit: the timeout fails it)."""
    child = subprocess.Popen([sys.executable, '-c', _FAILED_ANALYSIS], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, **OWN_PROCESS_GROUP)
    try:
        out, err = child.communicate(timeout=60)
    finally:  # its workers too, should it hang
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, signal.SIGKILL)
    assert child.returncode == 0, err
    pids = [int(pid) for pid in out.split()]
    assert len(pids) == 2
    wait_until(lambda: not any(_running(pid) for pid in pids), 30.0, 'the workers ended')


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (not gone, not a zombie waiting to be reaped)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ('Z', 'X')


def test_paths_before_start_is_an_error() -> None:
    with PlotWorkers(workers=1) as workers, pytest.raises(RuntimeError, match='start'):
        workers.paths()


@given(st.sets(st.sampled_from(COST_ORDER), min_size=1), st.integers(1, 5))
def test_shares_deal_every_plot_once_costliest_with_cheapest(names: set[str],
                                                             workers: int) -> None:
    dealt = shares(sorted(names), workers)
    assert sorted(n for share in dealt for n in share) == sorted(names)
    assert 1 <= len(dealt) <= workers and all(dealt)
    ordered = sorted(names, key=COST_ORDER.index)
    assert [share[0] for share in dealt] == ordered[:len(dealt)]  # the costliest first
    if len(names) == 2 * workers:  # each share: one of the costliest, one of the cheapest
        assert all(len(share) == 2 for share in dealt)
        assert dealt[0] == [ordered[0], ordered[-1]]


def test_log_scale_minor_ticks_at_two_and_five_per_decade() -> None:
    _, axes = figure(4, 3)
    ax = axes[0, 0]
    log_scale(ax)
    ax.set_ylim(1e-2, 1e2)
    minor = np.array([t for t in ax.yaxis.get_minorticklocs() if 1e-2 <= t <= 1e2])
    mantissa = minor / 10.0 ** np.floor(np.log10(minor) + 1e-12)
    assert_allclose(np.unique(np.round(mantissa, 6)), [2.0, 5.0])
    assert len(minor) == 2 * round(math.log10(1e2 / 1e-2))
