"""A positioner's base in the cell frame from tracker readings of its attachment point
(positioning_cell.coordinated.base_calibration): exact data recovered, a second solver, the
stated covariance against a Monte Carlo of the reading noise, refusals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from workspace import MECH, random_poses

from positioning_cell.coordinated.base_calibration import attachment_in_base, fit_base
from positioning_cell.errors import InputError

OFFSET = np.array([0.0, 0.0, 0.05])
TRUE_POSITION = np.array([1.2, -0.35, 0.02])
TRUE_ROTATION = Rotation.from_euler('xyz', [0.004, -0.003, 2.1])
SIGMA = 10e-6  # m, the tracker's reading noise


def _points(n: int, seed: int) -> np.ndarray:
    p, q = random_poses(n, np.random.default_rng(seed))
    return attachment_in_base(p, q, OFFSET)


def _measure(in_base: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    truth = TRUE_ROTATION.apply(in_base) + TRUE_POSITION
    noise = 0.0 if rng is None else rng.normal(0.0, SIGMA, truth.shape)
    out: np.ndarray = truth + noise
    return out


def _errors(fit_position: np.ndarray, fit_quaternion: np.ndarray) -> np.ndarray:
    """(δp, δθ) of a fit from the truth: m, rad about the cell axes."""
    turn = (Rotation.from_quat(fit_quaternion) * TRUE_ROTATION.inv()).as_rotvec()
    return np.r_[fit_position - TRUE_POSITION, turn]


def test_exact_readings_give_the_base_and_the_home_point_where_it_is() -> None:
    in_base = _points(8, 1)
    found = fit_base(in_base, _measure(in_base, None), SIGMA)
    assert np.abs(_errors(found.position, found.quaternion)).max() < 1e-12
    assert found.rms < 1e-12
    home = attachment_in_base(MECH.home_position, MECH.home_quaternion, OFFSET)
    np.testing.assert_allclose(found.to_cell(home), _measure(home, None), atol=1e-12)


def test_a_second_solver_finds_the_same_base() -> None:
    """scipy's nonlinear least squares on (p, rotation vector) from the identity, noisy data."""
    in_base = _points(8, 2)
    measured = _measure(in_base, np.random.default_rng(3))
    found = fit_base(in_base, measured, SIGMA)

    def residuals(x: np.ndarray) -> np.ndarray:
        out: np.ndarray = (Rotation.from_rotvec(x[3:]).apply(in_base) + x[:3] - measured).ravel()
        return out

    other = least_squares(residuals, np.r_[np.zeros(3), 0.0, 0.0, 2.0], xtol=1e-15,
                          ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(found.position, other.x[:3], atol=1e-9)
    turn = (Rotation.from_quat(found.quaternion) * Rotation.from_rotvec(other.x[3:]).inv())
    assert turn.magnitude() < 1e-9


def test_the_stated_covariance_is_the_scatter_of_the_fits() -> None:
    """400 fits of the same poses under fresh reading noise: each variance of (δp, δθ) within
    25 % of the stated one (4.5 standard errors of a variance from 400 draws), and the mean
    Mahalanobis distance² of the errors within 10 % of its 6 degrees of freedom."""
    in_base = _points(8, 4)
    rng = np.random.default_rng(5)
    fits = [fit_base(in_base, _measure(in_base, rng), SIGMA) for _ in range(400)]
    errors = np.array([_errors(f.position, f.quaternion) for f in fits])
    stated = fits[0].covariance / max(fits[0].variance_factor, 1.0)  # the noise's own share
    np.testing.assert_allclose(errors.var(axis=0), np.diag(stated), rtol=0.25)
    distances = np.einsum('ni,ij,nj->n', errors, np.linalg.inv(stated), errors)
    assert abs(distances.mean() - 6.0) < 0.6, distances.mean()
    factors = np.array([f.variance_factor for f in fits])
    assert abs(factors.mean() - 1.0) < 0.1  # the residuals tell the noise


def test_too_few_or_collinear_points_and_bad_values_are_refused() -> None:
    in_base = _points(8, 6)
    measured = _measure(in_base, None)
    with pytest.raises(InputError, match='at least 3'):
        fit_base(in_base[:2], measured[:2], SIGMA)
    line = np.outer(np.linspace(0.0, 0.01, 5), [1.0, 0.5, 0.2]) + [0.0, 0.0, 0.2]
    with pytest.raises(InputError, match='one line'):
        fit_base(line, _measure(line, None), SIGMA)
    with pytest.raises(InputError, match='finite'):
        fit_base(np.where(np.arange(24).reshape(8, 3) == 4, np.nan, in_base), measured, SIGMA)
    with pytest.raises(InputError, match='sigma'):
        fit_base(in_base, measured, 0.0)
    with pytest.raises(InputError, match='expected two'):
        fit_base(in_base, measured[:, :2], SIGMA)
