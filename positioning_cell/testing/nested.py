"""Comparing JSON-like trees (dicts, lists and tuples of numbers, strings, None) within a
tolerance: floats with ``numpy.testing.assert_allclose`` semantics (NaN equals NaN), every
other leaf exactly. For checks that two ways of computing a report (serially, on a Dask
cluster) give the same figures."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np


def assert_nested_close(actual: Any, expected: Any, rtol: float = 1e-12, atol: float = 0.0,
                        where: str = '') -> None:
    """AssertionError naming the first path (``['runs'][2]['start']``) where ``actual`` and
    ``expected`` differ: a different structure, keys, length, a string or an integer that is
    not equal, or a float beyond ``atol + rtol * |expected|`` (the units are the tree's:
    choose ``atol`` for the smallest figure compared)."""
    if isinstance(expected, Mapping):
        if not isinstance(actual, Mapping) or set(actual) != set(expected):
            raise AssertionError(f'{where or "top"}: keys {sorted(map(str, actual))} against '
                                 f'{sorted(map(str, expected))}' if isinstance(actual, Mapping)
                                 else f'{where or "top"}: {type(actual).__name__}, not a '
                                      'mapping')
        for key, value in expected.items():
            assert_nested_close(actual[key], value, rtol, atol, f'{where}[{key!r}]')
    elif isinstance(expected, (list, tuple)):
        if not isinstance(actual, (list, tuple)) or len(actual) != len(expected):
            raise AssertionError(f'{where or "top"}: {actual!r:.80} against {expected!r:.80}')
        for k, (a, e) in enumerate(zip(actual, expected, strict=True)):
            assert_nested_close(a, e, rtol, atol, f'{where}[{k}]')
    elif isinstance(expected, float) and not isinstance(actual, (bool, str)) \
            and isinstance(actual, (int, float)):
        np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol,
                                   err_msg=where or 'top')
    elif actual != expected or type(actual) is not type(expected):
        raise AssertionError(f'{where or "top"}: {actual!r} against {expected!r}')
