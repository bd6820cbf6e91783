"""Pose samplers over the positioner's workspace, shared by the property tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.core.limits import within_limits
from positioning_cell.core.mechanism import Mechanism

MECH = Mechanism.default()
# Half-widths of the sampled box around home: m, and rad of the rotation vector.
SPAN_POSITION = np.array([0.015, 0.015, 0.012])
SPAN_ROTATION = 0.12


def random_poses(n: int, rng: np.random.Generator,
                 mech: Mechanism = MECH) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """n poses uniformly in the sampled box, keeping only those within every limit."""
    p = mech.home_position + rng.uniform(-1.0, 1.0, (4 * n, 3)) * SPAN_POSITION
    q = Rotation.from_rotvec(rng.uniform(-1.0, 1.0, (4 * n, 3)) * SPAN_ROTATION).as_quat()
    ok = within_limits(mech, p, q)
    p, q = p[ok][:n], q[ok][:n]
    assert len(p) == n, 'sampled box too small a fraction within limits'
    return p, q


@st.composite
def poses(draw: st.DrawFn) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One pose in the sampled box (may violate limits; callers assume() as needed)."""
    unit = st.floats(-1.0, 1.0, allow_nan=False)
    dp = np.array([draw(unit) for _ in range(3)]) * SPAN_POSITION
    rv = np.array([draw(unit) for _ in range(3)]) * SPAN_ROTATION
    return MECH.home_position + dp, Rotation.from_rotvec(rv).as_quat()
