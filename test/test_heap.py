"""The analysing process's heap (positioning_cell.analysis.heap): with the mmap threshold
fixed, a large buffer freed goes back to the system even after a larger one has been freed
(which moves glibc's own threshold above it and keeps the next ones in the heap)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from positioning_cell.analysis.heap import LARGE_ALLOCATION

PROBE = """
import sys
import numpy as np
from positioning_cell.analysis.heap import map_large_allocations

def rss_kib():
    with open('/proc/self/status') as status:
        return next(int(line.split()[1]) for line in status if line.startswith('VmRSS'))

if sys.argv[1] == 'fixed':
    assert map_large_allocations()
big = np.ones(8 << 20, dtype=np.uint8)  # mapped; freed, it moves glibc's threshold to 8 MiB
del big
buffer = np.ones(2 << 20, dtype=np.uint8)  # a batch's buffer, every page touched
before = rss_kib()
del buffer
print(before - rss_kib())
"""


def _returned_kib(mode: str) -> int:
    env = {k: v for k, v in os.environ.items() if not k.startswith('MALLOC_')}
    done = subprocess.run([sys.executable, '-c', PROBE, mode], check=False, capture_output=True,
                          text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    return int(done.stdout.split()[-1])


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc only')
def test_a_freed_buffer_goes_back_to_the_system_once_the_threshold_is_fixed() -> None:
    assert LARGE_ALLOCATION <= 2 << 20
    assert _returned_kib('fixed') >= 1536  # its 2 MiB unmapped
    assert _returned_kib('moving') < 512  # glibc's own: kept in the heap
