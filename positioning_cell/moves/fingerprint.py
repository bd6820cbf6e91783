"""The key of a joint trajectory: what the drives answer each trajectory with, so that its
sender knows the answer is to what it sent. Its own module: the drives key what they receive
without loading the planner (:mod:`positioning_cell.moves.trajectory`)."""

from __future__ import annotations

import hashlib

import numpy as np
from numpy.typing import ArrayLike, NDArray


def wire_nanoseconds(times: ArrayLike) -> NDArray[np.int64]:
    """Times (s, >= 0) as the integer nanoseconds a builtin_interfaces Duration carries: the
    whole seconds and round(fraction × 1e9), at most 999 999 999
    (:func:`positioning_cell.ros.messages.duration` sends exactly this). A receiver that reads
    ``sec + nanosec × 1e-9`` back gets the same integers from this function: the key of a
    trajectory is the same on both ends."""
    t = np.asarray(times, dtype=float)
    whole = np.floor(t)
    fraction = np.minimum(np.round((t - whole) * 1e9), 999_999_999.0)
    ns: NDArray[np.int64] = whole.astype(np.int64) * 1_000_000_000 + fraction.astype(np.int64)
    return ns


def fingerprint(times: ArrayLike, positions: ArrayLike) -> str:
    """A short key of a joint trajectory: its point times as they go over the wire (integer
    ns, :func:`wire_nanoseconds`) and its last point's positions (m, rad, to 1e-12),
    JOINT_NAMES order. The drives answer each trajectory with its key, so the sender knows the
    answer is to what it sent (a trajectory that starts on receipt has no stamp to key by).
    Keyed by the µs of the times instead, a move of 1.1136255 s (1 113 625 500 ns on the wire)
    rounded to different µs on the two ends: the drives' answer matched nothing and the move
    was aborted ("timed out waiting for the leg driver to answer", make run)."""
    with np.errstate(invalid='ignore'):  # NaN / inf (a malformed trajectory) key too
        t_ns = wire_nanoseconds(times)
        final = np.round(np.asarray(positions, dtype=float)[-1] * 1e12).astype(np.int64)
    digest = hashlib.sha1(t_ns.tobytes() + final.tobytes(), usedforsecurity=False)
    return digest.hexdigest()[:12]
