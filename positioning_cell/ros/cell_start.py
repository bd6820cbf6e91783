"""A whole cell started for a run (``run_cell``): the recorder and the cell's nodes as
processes (as ``launch/cell.launch.py`` does on a ROS install) with the run's overrides (the
bag in the run folder, the run's marker topics recorded), and the wait until the run can
start: the recorder and the accuracy monitor subscribed and matched, the positioner homed and
taking goals, the monitor's verdict on the home pose in."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

import yaml
from numpy.typing import ArrayLike

from positioning_cell import names
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.processes import Processes

T = TypeVar('T')

#: The recorder first, then the cell's nodes (the launch file's list).
STARTED = (names.RECORDER, *names.CELL_NODES)
#: Topics the recorder and the monitor must have subscribed before the program starts.
RECORDED = (names.TARGET, names.MEASURED_POSE, names.TRACKER_REGISTRATION, names.TRUE_POSE,
            names.DIAGNOSTICS, names.PROGRAM)
MONITORED = (names.TARGET, names.MEASURED_POSE)
MONITOR_INPUTS = (*MONITORED, names.TRUE_POSE, names.TRACKER_REGISTRATION)
#: How long each stage of the start may take, s.
START_TIMEOUT = 60.0


class StartError(Exception):
    """The cell did not come up; the message says what is missing."""


def _wait(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    try:
        return wait_until(condition, timeout, what)
    except TimeoutError as err:
        raise StartError(str(err)) from err


def _call(what: Callable[[], T]) -> T:
    """A client call; a service that does not answer is a StartError."""
    try:
        return what()
    except TimeoutError as err:
        raise StartError(str(err)) from err


def new_run_folder(runs_dir: Path) -> Path:
    """A new run's folder, ``runs_dir/<UTC time, %Y%m%dT%H%M%SZ>`` ('_' appended while one of
    that name exists), created with its ``logs/``."""
    run_dir = runs_dir / time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())
    while run_dir.exists():
        run_dir = run_dir.with_name(run_dir.name + '_')
    (run_dir / 'logs').mkdir(parents=True)
    return run_dir


def run_overrides(run_dir: Path, description: Path | None = None) -> Path:
    """The run's parameter overrides, ``run_dir/run_overrides.yaml``: the recorder writes
    ``run_dir/bag``, also records the run driver's marker topics and stores the run's
    ``description`` file in the bag
    (:func:`positioning_cell.recording.description.write_description_file`)."""
    path = run_dir / 'run_overrides.yaml'
    pattern = '|'.join(re.escape(t) for t in (names.PROGRAM, names.AXIS_TEST,
                                              names.COMPLIANCE_TEST))
    recorder = {'output': str(run_dir / 'bag'), 'topic_pattern': pattern}
    if description is not None:
        recorder['description_file'] = str(description)
    path.write_text(yaml.safe_dump({names.NODE_RECORDER: {'ros__parameters': recorder}}))
    return path


def start_cell(procs: Processes, client: CellClient, config: Path, overrides: Path,
               first_pose: tuple[ArrayLike, ArrayLike], settle_timeout: float,
               say: Callable[[str], None]) -> None:
    """Start :data:`STARTED` in ``procs`` with the parameter files ``config`` and
    ``overrides`` and wait (module docstring) until the positioner would take ``first_pose``
    (position, quaternion in ``base``) and the monitor has judged the home pose (up to
    ``settle_timeout`` s; late: said, not an error). StartError naming what did not come, or
    the processes that exited."""
    for node in STARTED:
        procs.start(node.executable, params=[config, overrides])
    say(f'started {", ".join(n.executable for n in STARTED)}; waiting for the cell')

    def up(check: Callable[[], T]) -> Callable[[], T]:
        def probe() -> T:
            dead = procs.dead()
            if dead:
                raise StartError(f'{", ".join(dead)} exited during start-up (see the logs)')
            return check()
        return probe

    _wait(up(lambda: all(client.subscribed(t, names.NODE_RECORDER) for t in RECORDED)
             and all(client.subscribed(t, names.NODE_MONITOR) for t in MONITORED)),
          START_TIMEOUT, 'the recorder and the monitor to subscribe')
    # The monitor's own subscriptions must have matched the publishers (the graph above shows
    # only that they exist): a first target matched late would reach it after the tracker
    # samples that follow it, and the live figures of the first visit would differ from the
    # offline analysis of the bag.
    _wait(up(lambda: all(_call(client.monitor_report)['publishers'].get(t, 0) > 0
                         for t in MONITOR_INPUTS)), START_TIMEOUT,
          'the monitor to match the target, tracker, truth and registration publishers')

    def ready() -> bool:
        return _call(partial(client.plan, names.CHECK_POSE, *first_pose, 0.0, 30.0))

    done, message = _call(client.home)
    if not done:
        raise StartError(f'homing failed: {message}')
    say(f'homed: {message}')
    _wait(up(ready), START_TIMEOUT, 'the positioner to accept the first pose (encoder readings)')

    def home_settled() -> bool:
        """The monitor's verdict on the home pose is in (and the true pose settled there):
        a verdict arriving later would be taken for that of the program's first move."""
        report = _call(client.monitor_report)
        truth = report['truth']
        return (sum(report['verdicts'].values()) >= 1
                and (truth is None or len(truth['visits']) >= 1))

    try:
        _wait(up(home_settled), settle_timeout, 'the monitor to see the home pose settle')
    except StartError as err:
        say(f'run_cell: {err}; the first verdict may be late')
