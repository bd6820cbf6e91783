"""Calibration data as the identified model itself describes a machine: for testing the
identification and its adequacy test against known terms (not the simulator's truth, which
holds effects the model lacks: :mod:`positioning_cell.sim`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration import identify as idf
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.mechanics.statics import Payload, Structure

FloatArray = NDArray[np.float64]


def model_data(x: FloatArray, nominal: Mechanism, payload: Payload, structure: Structure,
               position: ArrayLike, quaternion: ArrayLike, pose_covariance: ArrayLike,
               joint_sigma: ArrayLike, conditions: Conditions,
               rng: np.random.Generator) -> idf.CalibrationData:
    """Data of the machine of vector ``x`` (COUNT,) at measured poses (N, 3) m, (N, 4): the
    encoder values :func:`~positioning_cell.calibration.identify.predicted_joints` gives under
    ``conditions`` (about the data's mean temperature, the reference identification takes),
    plus noise of the residual's own covariance (the tracker's ``pose_covariance`` (6, 6)
    through the inverse Jacobian and the encoders' ``joint_sigma`` (6,))."""
    p, q = as_pose_batch(position, quaternion)
    n = p.shape[0]
    t = conditions.temperature
    a = conditions.approach
    temperature = None if t is None else np.broadcast_to(np.asarray(t, dtype=float), (n,))
    approach = None if a is None else np.broadcast_to(np.asarray(a, dtype=float), (n, 6))
    data = idf.CalibrationData(np.zeros((n, 6)),
                               np.broadcast_to(np.asarray(joint_sigma, dtype=float), (n, 6)),
                               p, q, np.broadcast_to(np.asarray(pose_covariance, dtype=float),
                                                     (n, 6, 6)), temperature, approach)
    pred, _ = idf.predicted_joints(x, nominal, payload, structure, p, q,
                                   conditions=conditions,
                                   reference_temperature=idf.reference_temperature(data))
    white = idf.whitening(nominal, data)
    noise = np.linalg.solve(white, rng.normal(0.0, 1.0, (n, 6, 1)))[..., 0]
    return data._replace(joints=pred + noise)
