"""The panel's internal force as the legs' load cells say it (issue 27 item 4: the cross-check
of what the trackers cannot see).

Each positioner's leg driver reports its axes' efforts (leg forces N, θ torques N·m), the
``effort`` of its joint states: what holds its platform, its legs and what it carries. A set of
a coordinated cell carries no payload of its own (:func:`positioning_cell.ros.node_sets.
carried`), so what its efforts hold beyond its own platform and legs (τ − τ_own) is the panel's
wrench on its platform: w = J⁻ᵀ·(τ − τ_own) (seed 002 §2,
:func:`positioning_cell.mechanics.statics.wrench_from_efforts`), at the pose its encoders give
(the nominal model's forward kinematics: the machine's errors of tenths of a millimetre change
the Jacobian by parts in 10⁴). Turned into the cell frame, its force is minus the attachment's
force on the panel. The internal part is what remains once the panel's weight's own share is
taken away (the same cell with no misfit: :func:`~.internal_forces.wrench_map`'s ``by_load``,
in the panel frame at home: a panel turned by θ puts its weight's share off by about θ of
it, ~4 N of 440 N at 10 mrad). The largest over the attachments is comparable with the panel
simulator's ``largest_n``, the same quantity from its truth.

A strain that is the same at every pose (sockets installed off their file) is invisible to
the pose measurements a calibration uses; the load cells see it.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import GRAVITY, CellFile
from positioning_cell.coordinated.internal_forces import WrenchMap, wrench_map
from positioning_cell.coordinated.panel_motion import bases
from positioning_cell.core.kinematics import forward
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import (
    Payload,
    Structure,
    actuator_efforts,
    wrench_from_efforts,
)

FloatArray = NDArray[np.float64]


def attachment_forces(cell: CellFile, mech: Mechanism, joints: ArrayLike, efforts: ArrayLike,
                      structure: Structure | None = None) -> FloatArray:
    """Each attachment's force on the panel (N_sets, 3) N, cell frame, from each positioner's
    encoder values ``joints`` (N_sets, 6) (m, rad: leg1_length..leg3_length,
    leg1_theta..leg3_theta) and load-cell ``efforts`` (N_sets, 6) (N, N·m), in the cell's
    order; ``structure``: the positioners' own platform and legs (default
    :class:`~positioning_cell.mechanics.statics.Structure`). InputError for shapes that are
    not the cell's or a pose the encoders do not give."""
    n = len(cell.positioners)
    q = np.asarray(joints, dtype=float)
    tau = np.asarray(efforts, dtype=float)
    if q.shape != (n, 6) or tau.shape != (n, 6) or not (np.isfinite(q).all()
                                                         and np.isfinite(tau).all()):
        raise InputError(f'joints and efforts: expected ({n}, 6) finite values each, got '
                         f'{q.shape} and {tau.shape}')
    fk = forward(mech, q[:, :3], q[:, 3:])
    if not fk.converged.all():
        raise InputError('the encoder values give no platform pose for '
                         + ', '.join(e.name for e, ok in zip(cell.positioners, fk.converged,
                                                              strict=True) if not ok))
    out = np.empty((n, 3))
    for k, base in enumerate(bases(cell)):
        g = base.R.T @ np.asarray(GRAVITY)
        own = Payload(mass=0.0, gravity=(float(g[0]), float(g[1]), float(g[2])))
        held = actuator_efforts(mech, fk.position[k:k + 1], fk.quaternion[k:k + 1], own,
                                structure)
        # τ − τ_own = Jᵀ·w, w the platform's wrench on what pushes it: on the panel
        on_panel = wrench_from_efforts(mech, fk.position[k:k + 1], fk.quaternion[k:k + 1],
                                       tau[k:k + 1] - held)[0]
        out[k] = base.R @ on_panel[:3]
    return out


@functools.lru_cache(maxsize=16)
def cell_statics(cell: CellFile, mech: Mechanism) -> WrenchMap:
    """The linear statics of ``cell``'s panel under its weight
    (:func:`~.internal_forces.wrench_map`), once per cell file and machine: its mobility
    analysis takes tens of ms, and the load cells are read many times a second (the live
    view) on one file. Read-only: shared by every caller."""
    return wrench_map(cell.attachments(mech), cell.panel.stiffness, cell.panel.weight())


def internal_forces(cell: CellFile, mech: Mechanism, forces: ArrayLike) -> FloatArray:
    """The internal force at each attachment (N_sets, 3) N, cell frame: its force on the
    panel ``forces`` (N_sets, 3) N (:func:`attachment_forces`) less the panel's weight's own
    share (module docstring)."""
    share = cell_statics(cell, mech).by_load[:, :3]
    out: FloatArray = np.asarray(forces, dtype=float) - share
    return out


def internal_force_sizes(cell: CellFile, mech: Mechanism, forces: ArrayLike) -> FloatArray:
    """The internal force at each attachment (N_sets,) N: the size of
    :func:`internal_forces`."""
    out: FloatArray = np.linalg.norm(internal_forces(cell, mech, forces), axis=1)
    return out


def relaxing_steps(cell: CellFile, mech: Mechanism, forces: ArrayLike) -> FloatArray:
    """Each positioner's step (N_sets, 3) m, in its base frame, that takes away the internal
    force the load cells measure, ``forces`` (N_sets, 3) N (:func:`attachment_forces`): by
    the cell file's stiffness (seed 002 §3, :func:`~.internal_forces.wrench_map`), the
    attachments' forces are the weight's share plus A·δ for attachment displacements δ; the
    least-norm δ that gives the measured forces less that share (least squares: what no
    displacement gives, e.g. the load cells' own error, is left) is the misfit, and −δ its
    relaxing step. Least-norm: no rigid motion of the panel (which loads nothing) is in it.
    A real panel's stiffness is not the file's: a step leaves part of the force (its
    relative error), which a second one takes away (:meth:`~.coordinator.Coordinator.
    relax_forces`)."""
    n = len(cell.positioners)
    f = np.asarray(forces, dtype=float)
    if f.shape != (n, 3) or not np.isfinite(f).all():
        raise InputError(f'forces: expected ({n}, 3) finite values, got {f.shape}')
    linear = cell_statics(cell, mech)
    force_rows = (6 * np.arange(n)[:, None] + np.arange(3)).ravel()
    a = linear.matrix[np.ix_(force_rows, force_rows)]  # forces per attachment translation
    misfit, *_ = np.linalg.lstsq(a, (f - linear.by_load[:, :3]).ravel(), rcond=None)
    steps_cell = -misfit.reshape(n, 3)
    out: FloatArray = np.array([base.R.T @ step
                                for base, step in zip(bases(cell), steps_cell, strict=True)])
    return out
