"""Test-wide settings: nothing depends on the caller's ROS environment; and the tiers: a test
module marked ``nodes`` or ``slow`` at its top (``pytestmark``) is not even imported when the
``-m`` expression leaves its marks out, so ``-m "not nodes and not slow"`` (``make
test-library``) runs the library's tests without loading rclpy. Nothing here imports rclpy."""

from __future__ import annotations

import ast
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from positioning_cell.config import config_path

_TMP = Path(os.environ.get('POSITIONING_CELL_TEST_TMP', tempfile.gettempdir())) / (
    f'positioning_cell_test_{os.getuid()}')
os.environ.setdefault('ROS_LOG_DIR', str(_TMP / 'ros_log'))
os.environ.setdefault('ROS_HOME', str(_TMP / 'ros_home'))
# Loopback only (docs/howto/network.md), as positioning_cell.ros.client.cell_environment gives the
# cell's processes: the shipped Fast DDS profile with discovery left to it (with LOCALHOST,
# rmw_fastrtps adds a transport on every interface); a caller's own profile with LOCALHOST.
_PROFILE = config_path('fastdds_loopback.xml').resolve()
os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(_PROFILE))
os.environ.pop('ROS_LOCALHOST_ONLY', None)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = (
    'SYSTEM_DEFAULT' if Path(os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']).resolve() == _PROFILE
    else 'LOCALHOST')
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ.setdefault('MPLBACKEND', 'Agg')
os.environ.pop('RMW_IMPLEMENTATION', None)
# One BLAS thread in every test process and what it starts (set before numpy loads: nothing
# above imports it): the suite's parallelism is its workers', three on two cores, and
# OpenBLAS's own threads, one per core in each, only contended with them. With one
# (benchmarks/suite_cpu.py, 2-core VM, one run each, issue 24): the parallel tier 919 s of
# CPU and 494 s against 1009 s and 542 s; the library tier alone (make test-library's
# selection, three workers) 344 s and 178 s against 435 s and 222 s; every test passed each
# way. Given values are kept.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

# Deterministic property tests: the same examples on every run and machine.
settings.register_profile('ci', derandomize=True, deadline=None, max_examples=150,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile('ci')


def _interrupted(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f'{signal.Signals(signum).name} received')


def pytest_configure(config: pytest.Config) -> None:
    """A SIGTERM (a runner's time limit, a kill) ends the run as Ctrl-C does: pytest unwinds,
    each fixture's teardown stops the processes its test started (they run in sessions of
    their own, which no signal to pytest's group reaches)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupted)


def module_marks(path: Path) -> set[str]:
    """The marks a test module gives all its tests (``pytestmark = pytest.mark.X`` or a list
    of them), read from its source without importing it."""
    for node in ast.parse(path.read_text(encoding='utf-8'), str(path)).body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == 'pytestmark' for t in node.targets):
            return {n.attr for n in ast.walk(node.value) if isinstance(n, ast.Attribute)
                    and isinstance(n.value, ast.Attribute) and n.value.attr == 'mark'}
    return set()


def decorated_marks(path: Path) -> list[set[str]]:
    """The marks each test function or class of a module adds with a ``@pytest.mark.X``
    decorator (those with none left out), read from its source."""
    found = []
    for node in ast.parse(path.read_text(encoding='utf-8'), str(path)).body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            marks = {n.attr for d in node.decorator_list for n in ast.walk(d)
                     if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Attribute)
                     and n.value.attr == 'mark'}
            if marks:
                found.append(marks)
    return found


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Leave out a module none of whose tests the ``-m`` expression can select (its imports,
    rclpy among them, are never run): neither with the module's own marks, nor with those
    plus a test's own decorator marks (a ``@pytest.mark.timing`` test in a module marked
    ``nodes`` runs in the timing tier; it used to be left out of both tiers). Anything else is
    collected as usual."""
    expression = config.getoption('markexpr')
    if not expression or collection_path.suffix != '.py' \
            or not collection_path.name.startswith('test_'):
        return None
    marks = module_marks(collection_path)
    if not marks:
        return None
    from _pytest.mark.expression import Expression

    compiled = Expression.compile(expression)
    for possible in [marks, *(marks | own for own in decorated_marks(collection_path))]:
        if compiled.evaluate(lambda name, _marks=possible, **_: name in _marks):
            return None
    return True


#: The parallel tier's longest modules, longest first (worker seconds on the 2-core VM, issue
#: 24: run_cell 69, shutdown 47, fault_trials 41, docs 38, calibrator_node 38, package 28,
#: bag_layouts 24, replay 17; panel_calibration 72 alone, run_coordinated 64 alone, issue
#: 27): collected before the others, so that a serial run (the timing tier) and a worker
#: given modules in collection order start them first. ``make test``'s parallel tier does
#: not: pytest-xdist 3.8's ``--dist loadscope`` hands out the modules with the most tests
#: first (its default ``--loadscope-reorder``), this order breaking only ties, so run_cell,
#: run_coordinated and panel_calibration (one or two tests each) start late. In this order
#: (``--no-loadscope-reorder``) the tier took 654 s against 621 s in xdist's (2026-12-07,
#: one run each on the 2-core VM: its wall time is bound by its CPU, not by the order), so
#: the Makefile keeps xdist's.
LONGEST_FIRST = ('test_run_cell.py', 'test_panel_calibration.py', 'test_run_coordinated.py',
                 'test_shutdown.py', 'test_fault_trials.py', 'test_docs.py',
                 'test_calibrator_node.py', 'test_package.py', 'test_bag_layouts.py',
                 'test_replay.py')


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules of :data:`LONGEST_FIRST` first, in its order; the rest as collected (a
    stable sort: each module's tests keep their order)."""
    missing = [name for name in LONGEST_FIRST if not (Path(__file__).parent / name).is_file()]
    if missing:  # a renamed module would silently lose its place
        raise pytest.UsageError(f'conftest.LONGEST_FIRST names no test module: {missing}')
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture
def ros() -> Iterator[Any]:
    """The in-process tier's rclpy context: nodes built in the test process on a private
    domain (cell_harness.InProcess), all stopped at the end."""
    from cell_harness import in_process

    with in_process() as context:
        yield context
