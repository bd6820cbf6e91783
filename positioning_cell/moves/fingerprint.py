"""The key of a joint trajectory: what the drives answer each trajectory with, so that its
sender knows the answer is to what it sent. Its own module: the drives key what they receive
without loading the planner (:mod:`positioning_cell.moves.trajectory`)."""

from __future__ import annotations

import hashlib

import numpy as np
from numpy.typing import ArrayLike


def fingerprint(times: ArrayLike, positions: ArrayLike) -> str:
    """A short key of a joint trajectory: its point times (s, to the µs) and its last point's
    positions (m, rad, to 1e-12), JOINT_NAMES order. The drives answer each trajectory with
    its key, so the sender knows the answer is to what it sent (a trajectory that starts on
    receipt has no stamp to key by)."""
    with np.errstate(invalid='ignore'):  # NaN / inf (a malformed trajectory) key too
        t_us = np.round(np.asarray(times, dtype=float) * 1e6).astype(np.int64)
        final = np.round(np.asarray(positions, dtype=float)[-1] * 1e12).astype(np.int64)
    digest = hashlib.sha1(t_us.tobytes() + final.tobytes(), usedforsecurity=False)
    return digest.hexdigest()[:12]
