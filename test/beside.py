"""make test's last step: one pytest run in the foreground and, beside it, another at idle CPU
priority (Linux SCHED_IDLE: it runs only on a core that nothing else wants, and any other
process that wakes takes the core back at once), so that the second fills the time the first
leaves a core idle without being a load the first can see.

    python test/beside.py <pytest arguments> -- <pytest arguments of the run beside>

The Makefile runs the timing tier (``-m timing``: one test at a time, about one core busy)
with the library tier (no process, no ROS, no clock judged) beside it: the timing tests keep
the machine as if alone. The run beside prints its output after the foreground's has ended;
the exit status is the foreground's, or the other's if the foreground passed. Where the
scheduling class cannot be set, the run beside gets nice 19 instead (and says so)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from types import FrameType


def _idle() -> None:
    """In the child before it runs pytest: the idle scheduling class, else the lowest nice."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError) as err:
        os.nice(19)
        print(f'beside: no SCHED_IDLE ({err}); nice 19 instead', file=sys.stderr)


def main(argv: list[str]) -> int:
    """Run both (module docstring); the exit status."""
    if argv.count('--') != 1:
        print('usage: beside.py <pytest arguments> -- <pytest arguments of the run beside>',
              file=sys.stderr)
        return 2
    split = argv.index('--')
    foreground, background = argv[:split], argv[split + 1:]
    pytest = [sys.executable, '-m', 'pytest']
    with tempfile.TemporaryFile('w+', encoding='utf-8') as log:
        beside = subprocess.Popen([*pytest, *background], stdout=log, stderr=subprocess.STDOUT,
                                  preexec_fn=_idle)  # noqa: PLW1509 (no thread yet)
        first = subprocess.Popen([*pytest, *foreground])
        runs = (first, beside)

        def forward(signum: int, frame: FrameType | None) -> None:
            for run in runs:
                run.send_signal(signum)

        # A Ctrl-C reaches both pytest runs from the terminal: each stops its tests and
        # tears them down (every process they started stopped), and this one waits for them.
        # A SIGTERM to this one alone is passed on.
        signal.signal(signal.SIGINT, lambda signum, frame: None)
        signal.signal(signal.SIGTERM, forward)
        status, other = first.wait(), beside.wait()
        log.seek(0)
        print(f'\n== beside it, at idle CPU priority: pytest {" ".join(background)}',
              flush=True)
        sys.stdout.write(log.read())
        sys.stdout.flush()
    return status or other


if __name__ == '__main__':
    raise SystemExit(main(sys.argv[1:]))
