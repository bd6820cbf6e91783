"""The analysing process's heap: large buffers mapped apart from it, so that what one batch of
a bag frees goes back to the system instead of staying in the heap (issue 24).

glibc maps an allocation of at least M_MMAP_THRESHOLD bytes apart from the heap and unmaps it
when freed. The threshold starts at 128 KiB but rises to the size of each mapped buffer freed
(up to 32 MiB): after the first block of a bag has been decoded, the next blocks' arrays come
from the heap, whose top is held by the small objects the analysis keeps (its visits, sums and
segments) between them, so the heap only grows. On a `make run` bag tiled to 1 M and to 4 M
messages, ``analyse_bag``'s peak RSS (ad hoc, 2-core VM): 136 and 175 MiB with the moving
threshold (1.29 x), 125 and 145 MiB with it fixed at 512 KiB (1.16 x), for 2-11 % more time
(the mapped pages are zeroed at each use). :func:`map_large_allocations` fixes it, which also
stops it moving (glibc's mallopt, documented in ``mallopt(3)``).
"""

from __future__ import annotations

import ctypes

#: mallopt's parameter number of M_MMAP_THRESHOLD (glibc's malloc.h).
M_MMAP_THRESHOLD = -3
#: Allocations of at least this many bytes (a block's arrays, the decoded batches) are mapped
#: apart from the heap and returned to the system when freed.
LARGE_ALLOCATION = 512 * 1024


def map_large_allocations(threshold: int = LARGE_ALLOCATION) -> bool:
    """Map allocations of at least ``threshold`` bytes apart from the heap in this process from
    now on (a fixed M_MMAP_THRESHOLD). False where the C library has no such setting (not
    glibc): nothing is changed there."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, threshold))
