"""The error budget of a recorded run (:mod:`.error_budget`): a second pass over the bag, once
the replay has found the settled visits, that gathers per visit what happened inside its settle
window: the tracker's measurements and the simulation truth (count, mean, scatter), the
encoders (/legs/joint_states, mean) and the last commanded joints before the window ended (the
last point of the last /legs/joint_trajectory logged by then). Batch by batch, vectorised over
the samples (:class:`.error_budget.WindowStats`); memory is the visits' sums plus the
trajectories' final points.

The sensitivities J_n come from the nominal mechanism at the commanded pose
(:func:`positioning_cell.core.kinematics.jacobian`); the encoder resolution from the drives'
``encoder:`` settings. The truth judges only; nothing here feeds back into the cell.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from positioning_cell.analysis.error_budget import (
    ErrorBudget,
    WindowStats,
    error_budget,
    last_before,
)
from positioning_cell.analysis.reading import Recording, joint_values
from positioning_cell.analysis.replay import OUTSIDE_PROGRAM, LabelledVisit
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.names import JOINT_STATES, JOINT_TRAJECTORY, MEASURED_POSE, TRUE_POSE

FloatArray = NDArray[np.float64]

#: The topics the budget's pass reads.
BUDGET_TOPICS = (MEASURED_POSE, TRUE_POSE, JOINT_STATES, JOINT_TRAJECTORY)


def gather(recording: Recording, visits: Sequence[LabelledVisit], mech: Mechanism | None,
           resolution: FloatArray | None) -> tuple[ErrorBudget, ...]:
    """The budget of each mode of the program (in order of first appearance; the visits
    before the program are left out) from the bag, a second time through it."""
    mine = [v for v in visits if v.mode != OUTSIDE_PROGRAM]
    if not mine:
        return ()
    starts = np.array([v.visit.window_start for v in mine])
    stops = np.array([v.visit.settle_time for v in mine])
    p_cmd = np.array([v.visit.commanded_position for v in mine])
    q_cmd = np.array([v.visit.commanded_quaternion for v in mine])
    measured = WindowStats(starts, stops, p_cmd)
    truth = WindowStats(starts, stops, p_cmd)
    encoders = WindowStats(starts, stops, np.zeros((len(mine), 6)))
    sent_at: list[float] = []
    sent: list[FloatArray] = []
    for batch in recording.batches():
        if batch.measured.count:
            measured.add(batch.measured.stamp, batch.measured.position)
        if batch.truth.count:
            truth.add(batch.truth.stamp, batch.truth.position)
        if batch.joint_states.count:
            encoders.add(batch.joint_states.stamp, batch.joint_states.position)
        for log_ns, names, last in batch.trajectories:  # one per move or correction: few
            if last is not None:
                sent_at.append(log_ns * 1e-9)
                sent.append(joint_values(list(names), last.tolist()))
    has_truth = bool(truth.count.sum())
    commanded = last_before(np.array(sent_at), np.array(sent).reshape(-1, 6), stops)
    servo = encoders.mean() - commanded if encoders.count.sum() and sent else None
    jac = None if mech is None else kinematics.jacobian(mech, p_cmd, q_cmd).matrix[:, :3, :]
    out = []
    for mode in dict.fromkeys(v.mode for v in mine):
        rows = np.array([v.mode == mode for v in mine])
        out.append(error_budget(
            mode, (truth.mean() - p_cmd)[rows] if has_truth else None,
            None if servo is None else servo[rows], None if jac is None else jac[rows],
            resolution, measured.variance_of_mean()[rows],
            (measured.mean() - truth.mean())[rows] if has_truth else None, int(rows.sum())))
    return tuple(out)
