"""Vector algebra on batches of 3-vectors, where numpy's general routine is slow for the small
arrays of one pose at a time."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def cross(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a × b for (..., 3) vectors, broadcast against each other as ``np.cross(a, b)`` does
    (checked against it by test_vectors). ``np.cross`` moves axes and checks shapes on every
    call: ~17 µs on the arrays of one pose: the simulated machine's statics call it some thirty
    times a true pose (its fixed point, sim/truth.py); this takes ~7 µs."""
    u, v = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if u.shape[-1:] != (3,) or v.shape[-1:] != (3,):
        raise ValueError(f'cross: expected (..., 3) vectors, got {u.shape} and {v.shape}')
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[..., 0] = u1 * v2 - u2 * v1
    out[..., 1] = u2 * v0 - u0 * v2
    out[..., 2] = u0 * v1 - u1 * v0
    return out
