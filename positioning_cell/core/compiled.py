"""Compilation of the per-sample kernels of the hot paths (forward kinematics, Monte Carlo).

A kernel is a plain Python function over float64 arrays and scalars, compiled by numba to
machine code on its first call and cached on disk (``__pycache__`` beside the module, or
numba's user-wide cache where that is read-only), so later processes load it in a fraction
of a second instead of compiling for several.
Kernels are serial (one core), release the GIL, and follow numpy's floating-point rules
(division by zero gives inf or NaN, never an exception); no fast-math, so results match the
order of operations written.

numba itself (~125 MB of a process, a third of a second and more to import) is loaded only
where a kernel runs: a kernel is handed to numba on its first call (or by :func:`load`). A node
that runs kernels runs each of them once while it is built (its ``warm_up``: numba imported,
every specialisation it will call loaded from the disk cache) and is then *sealed*
(:func:`seal`, by :func:`positioning_cell.ros.spin.run` before the node spins): from then on
a kernel that was not warmed, or a call that would compile a new specialisation, raises
:class:`ColdKernelError` instead of pausing the node's executor for the import or the compile.
A node that never runs a kernel never imports numba. The cell's nodes run none: they solve
forward kinematics one pose at a time, and :func:`positioning_cell.core.kinematics.forward`
runs small batches, and every batch in a sealed process without numba, as the kernel's Python
source (``py_func``, ~0.1 ms a pose) instead of loading numba for them; the seal stays the
guard against a kernel compiled or loaded from a callback.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

Kernel = TypeVar('Kernel', bound=Callable[..., Any])

#: The kernels declared and not yet handed to numba, and the lock of that hand-over.
_PENDING: list[Callable[..., Any]] = []
#: The numba dispatchers made so far.
_DISPATCHERS: list[Any] = []
_LOCK = threading.Lock()
#: Set by :func:`seal`.
_SEALED = threading.Event()


class ColdKernelError(RuntimeError):
    """A kernel called in a sealed process (a node spinning) that was not warmed while the node
    was built: its import or compile would stall the node's executor."""


def kernel(function: Kernel) -> Kernel:
    """``function`` compiled in nopython mode, with the same signature for callers and mypy.

    Nothing is compiled or imported here: on the first call of any kernel (or :func:`load`),
    every kernel declared so far becomes a numba dispatcher, bound under its own name in its
    module (so a kernel calling another one compiles against the dispatcher; callers look
    kernels up as module globals). The uncompiled original stays reachable as ``.py_func``.
    """
    with _LOCK:
        _PENDING.append(function)

    @functools.wraps(function)
    def first_call(*args: Any) -> Any:
        return _dispatcher(function)(*args)

    first_call.py_func = function  # type: ignore[attr-defined]
    return cast(Kernel, first_call)


def load() -> None:
    """Hand every kernel declared so far to numba (imports numba; compiles nothing)."""
    with _LOCK:
        if _SEALED.is_set() and _PENDING:
            raise ColdKernelError(
                f'kernel {_PENDING[0].__module__}.{_PENDING[0].__name__} called after the '
                'process was sealed without being warmed: warm it while the node is built')
        if _PENDING:
            import numba  # only where a kernel runs: the point of this module's laziness

            for pending in _PENDING:
                dispatcher = numba.njit(cache=True, nogil=True, error_model='numpy')(pending)
                pending.__globals__[pending.__name__] = dispatcher
                _DISPATCHERS.append(dispatcher)
            _PENDING.clear()


def _dispatcher(function: Callable[..., Any]) -> Any:
    """The numba dispatcher of the kernel ``function`` (every pending kernel made one)."""
    load()
    return function.__globals__[function.__name__]


def seal() -> None:
    """From now on no kernel is imported or compiled in this process: a kernel that has not run
    yet, or a call that needs a new specialisation of one that has, raises
    :class:`ColdKernelError` (numba's TypeError "No matching definition" for the latter). A
    node calls this (through :func:`positioning_cell.ros.spin.run`) once it is built, after its
    warm-up, before it spins. Without numba loaded, only the flag is set: a kernel call then
    raises before importing it."""
    with _LOCK:
        _SEALED.set()
        for dispatcher in _DISPATCHERS:
            if dispatcher.signatures:
                dispatcher.disable_compile()
            else:  # declared but never run: any call would compile it
                name = dispatcher.py_func.__name__
                dispatcher.py_func.__globals__[name] = _cold(dispatcher.py_func)


def _cold(function: Callable[..., Any]) -> Callable[..., Any]:
    """What a never-run kernel becomes at :func:`seal`: a function that raises."""
    @functools.wraps(function)
    def cold(*args: Any) -> Any:
        raise ColdKernelError(f'kernel {function.__module__}.{function.__name__} called after '
                              'the process was sealed without being warmed: warm it while the '
                              'node is built')

    return cold


def source(function: Kernel) -> Kernel:
    """The kernel ``function``'s Python source, uncompiled (its ``py_func``): the same
    operations at interpreter speed, without loading numba."""
    return cast(Kernel, function.py_func)  # type: ignore[attr-defined]


def loaded() -> bool:
    """Whether numba is loaded in this process (a kernel has been handed to it)."""
    return bool(_DISPATCHERS)


def sealed() -> bool:
    """Whether :func:`seal` has been called in this process."""
    return _SEALED.is_set()


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
