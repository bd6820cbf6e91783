"""The static load rig of the compliance test (ISO 9283:1998 §10), simulated: a force actuator
that pushes on the platform origin with a commanded force (base frame, N), regulated on its own
load cell, whose reading is what the rig reports.

The load cell is not exact: the force the rig really applies is its reading times
1 + ``truth.load_rig.force_error`` (a calibration error the rig does not know; the cell knows
only the rig's stated accuracy, the compliance test's ``force_accuracy``). The force really
applied joins the payload's external wrench (:class:`~positioning_cell.mechanics.statics
.Payload`), so the machine's compliance (:mod:`positioning_cell.sim.effects.compliance`) and
its load-driven clearance respond to it as to any other load. Only the simulators read this.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import Payload
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LoadRigTruth:
    """``truth.load_rig``: how far the rig's real force is from its load cell's reading."""

    force_error: float = setting(0.002, 'the real force over the load cell\'s reading, minus 1 '
                                 '(its calibration error)', '1', low=-0.05, high=0.05)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class LoadRig:
    """``load_rig``: the rig as the cell knows it, its largest force (a command beyond it is
    refused)."""

    max_force: float = setting(1000.0, 'the largest force the rig applies', 'N', low=0.0,
                               low_open=True, high=1e5)

    def __post_init__(self) -> None:
        check_fields(self)


def checked_force(rig: LoadRig, force: ArrayLike) -> FloatArray:
    """A commanded force (3,) N, base frame, as floats; InputError naming what is wrong when it
    is not three finite numbers within the rig's ``max_force``."""
    f = np.asarray(force, dtype=float)
    if f.shape != (3,) or not np.all(np.isfinite(f)):
        raise InputError(f'load rig: a force is three finite numbers (N), got {f.tolist()}')
    if np.linalg.norm(f) > rig.max_force:
        raise InputError(f'load rig: {np.linalg.norm(f):.1f} N is beyond its largest force '
                         f'{rig.max_force:g} N')
    return f


def loaded_payload(payload: Payload, truth: LoadRigTruth, reading: FloatArray) -> Payload:
    """``payload`` with the force the rig really applies when its load cell reads ``reading``
    (3,) N added to its external force (base frame, at the platform origin: no moment)."""
    fx, fy, fz = (float(v) for v in np.asarray(payload.external_wrench[:3])
                  + reading * (1.0 + truth.force_error))
    return replace(payload, external_wrench=(fx, fy, fz, *payload.external_wrench[3:]))
