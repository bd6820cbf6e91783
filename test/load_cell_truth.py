"""What the sets' encoders and load cells read with the panel simulator's truth holding the
panel (the efforts as the simulated drives give them: their own platform and legs, and the
panel's push, τ = Jᵀ·−w). Used by test_load_cells and test_coordinator."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.coordinated.cell_file import GRAVITY
from positioning_cell.coordinated.panel_motion import bases
from positioning_cell.core.kinematics import inverse
from positioning_cell.mechanics.statics import (
    Payload,
    Structure,
    actuator_efforts,
    efforts_from_wrench,
)
from positioning_cell.sim.panel import PanelTruth


def set_readings(truth: PanelTruth, platforms: Sequence[tuple[ArrayLike, ArrayLike]]
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Each set's encoder values (N, 6) and load-cell efforts (N, 6) with its platform at
    ``platforms`` (position, quaternion; its base frame), and the ``truth``'s largest internal
    force N there."""
    state = truth.state(platforms)
    mech = truth.mech
    joints, efforts = [], []
    for entry, base, (p_, q_) in zip(truth.cell.positioners, bases(truth.cell), platforms,
                                     strict=True):
        p, q = np.asarray(p_, dtype=float), np.asarray(q_, dtype=float)
        ik = inverse(mech, p, q)
        joints.append(np.concatenate([ik.lengths[0], ik.thetas[0]]))
        g = base.R.T @ np.asarray(GRAVITY)
        own = actuator_efforts(mech, p[None], q[None], Payload(mass=0.0, gravity=tuple(g)),
                               Structure())
        pushed = state.on_platforms[entry.name]
        efforts.append(own[0] + efforts_from_wrench(mech, p[None], q[None], -pushed[None])[0])
    return np.array(joints), np.array(efforts), state.largest
