"""Compilation of the per-sample kernels of the hot paths (forward kinematics, Monte Carlo).

A kernel is a plain Python function over float64 arrays and scalars, compiled by numba to
machine code on its first call and cached on disk (``__pycache__`` beside the module, or
numba's user-wide cache where that is read-only), so later processes load it in a fraction
of a second instead of compiling for several.
Kernels are serial (one core), release the GIL, and follow numpy's floating-point rules
(division by zero gives inf or NaN, never an exception); no fast-math, so results match the
order of operations written.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

Kernel = TypeVar('Kernel', bound=Callable[..., Any])


def kernel(function: Kernel) -> Kernel:
    """``function`` compiled in nopython mode, with the same signature for callers and mypy.

    The uncompiled original stays reachable as ``.py_func`` (tests step through it).
    """
    return cast(Kernel, numba.njit(cache=True, nogil=True, error_model='numpy')(function))


def kernel_array(value: ArrayLike, dtype: DTypeLike = np.float64) -> NDArray[Any]:
    """``value`` as a C-contiguous, aligned, writeable array of ``dtype`` (a copy only where
    needed): every call of a kernel then meets the one specialisation compiled for it, never a
    new one for a read-only or strided argument."""
    return np.require(value, dtype, ['C', 'A', 'W'])


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API on this platform
        return max(1, os.cpu_count() or 1)
