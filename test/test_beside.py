"""test/beside.py, make test's last step: the run beside at idle CPU priority, its output after
the foreground's, the exit status of whichever failed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any, ClassVar

import beside
import pytest

HERE = Path(__file__).resolve().parent


def test_the_run_beside_gets_the_idle_scheduling_class() -> None:
    code = ('import os, beside; beside._idle(); '
            'print(os.sched_getscheduler(0), os.nice(0))')
    said = subprocess.run([sys.executable, '-c', code], cwd=HERE, capture_output=True,
                          text=True, check=True, timeout=60).stdout.split()
    policy, nice = int(said[0]), int(said[1])
    assert policy == os.SCHED_IDLE or nice == 19, said


class _Run:
    """A pytest run as subprocess.Popen would start it: ``codes`` by its last argument."""

    codes: ClassVar[dict[str, int]] = {}
    started: ClassVar[list[tuple[list[str], Any]]] = []

    def __init__(self, command: list[str], stdout: Any = None, stderr: Any = None,
                 preexec_fn: Any = None) -> None:
        self.command, self.stdout, self.idle = command, stdout, preexec_fn is not None
        _Run.started.append((command, preexec_fn))
        if stdout is not None:
            stdout.write(f'output of {command[-1]}\n')

    def wait(self) -> int:
        return _Run.codes[self.command[-1]]

    def send_signal(self, signum: int) -> None:
        pass


@pytest.mark.parametrize(('first', 'other', 'status'), [(0, 0, 0), (1, 0, 1), (0, 1, 1),
                                                        (2, 1, 2)])
def test_the_status_is_the_foregrounds_unless_it_passed(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], first: int,
        other: int, status: int) -> None:
    monkeypatch.setattr(beside.subprocess, 'Popen', _Run)
    monkeypatch.setattr(beside.signal, 'signal', lambda *args: None)  # this process's own
    _Run.codes, _Run.started = {'fg': first, 'bg': other}, []
    assert beside.main(['-m', 'fg', '--', '-m', 'bg']) == status
    (bg, idle), (fg, none) = _Run.started
    assert bg[-2:] == ['-m', 'bg'] and idle is beside._idle
    assert fg[-2:] == ['-m', 'fg'] and none is None
    out = capsys.readouterr().out
    assert out.index('beside it, at idle CPU priority: pytest -m bg') < out.index('output of bg')


def test_without_one_separator_it_says_how_to_call_it(capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    assert beside.main(['-m', 'timing']) == 2
    assert 'usage: beside.py' in capsys.readouterr().err
