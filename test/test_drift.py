"""Drift of pose characteristics (ISO 9283 §7.6, positioning_cell.accuracy.drift): a hand-worked
example, the epochs, bad input, and the figures of seeded runs from their true poses within U
of those from their measurements."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from positioning_cell.accuracy.drift import FIGURES, drift_figures, epoch_size
from positioning_cell.accuracy.figure_uncertainty import pose_figure_uncertainty
from positioning_cell.errors import InputError

C = np.array([0.010, -0.020, 0.190])
Q = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize(('n', 'm'), [(6, 2), (8, 2), (9, 3), (15, 5), (30, 10), (31, 10)])
def test_each_epoch_is_a_third_of_the_visits(n: int, m: int) -> None:
    assert epoch_size(n) == m


def test_a_hand_worked_example() -> None:
    """Six visits, epochs of two. The first two at C + (2, 0, 0) µm and C + (4, 0, 0) µm:
    AP_p 3 µm, l_j 1, 1 µm, S_l 0, RP_l 1 µm. The last two at C + (0, 0, 10) µm and
    C + (0, 0, 14) µm: AP_p 12 µm, RP_l 2 µm. dAP_p 9 µm, dRP_l 1 µm. Turned about z by
    0.001 and 0.003 rad first, 0.002 rad twice last: AP_c 2 mrad both (dAP_c 0), RP_c
    3·√2 mrad first and 0 last (dRP_c 3√2 mrad). The middle visits, given out of order in
    time, are in neither epoch."""
    x = np.array([[0.0, 0.0, 10e-6], [2e-6, 0, 0], [50e-6, 0, 0], [4e-6, 0, 0],
                  [-50e-6, 0, 0], [0, 0, 14e-6]]) + C
    angle = np.array([0.002, 0.001, 0.0, 0.003, 0.0, 0.002])
    q = Rotation.from_rotvec(np.outer(angle, [0.0, 0.0, 1.0])).as_quat()
    times = np.array([50.0, 0.0, 20.0, 10.0, 30.0, 60.0])
    d = drift_figures(C, Q, x, q, times)
    assert d.cycles == 2 and d.time_first == pytest.approx(5.0) and d.span == pytest.approx(50.0)
    assert d.first.ap_p == pytest.approx(3e-6, abs=1e-12)
    assert d.last.ap_p == pytest.approx(12e-6, abs=1e-12)
    assert d.dap_p == pytest.approx(9e-6, abs=1e-12)
    assert d.drp_l == pytest.approx(1e-6, abs=1e-12)
    assert d.dap_c == pytest.approx(0.0, abs=1e-12)
    assert d.drp_c == pytest.approx(3 * math.sqrt(2) * 1e-3, rel=1e-9)
    assert math.isnan(d.u_dap_p)  # no covariance stated


def test_u_combines_the_epochs_us_and_the_record_is_json() -> None:
    """dAP's U the quadrature of the epochs' (their errors' correlation is ≥ 0), dRP's the
    sum (bounds; both epochs from one Monte Carlo, each within its 1 % tolerance of the
    epoch's own); a U not stated is null in JSON."""
    sigma = 3e-6
    x = np.array([C, C, C, C, C + [0.0, 5e-6, 0.0], C + [0.0, 5e-6, 0.0]])
    cov = np.tile(np.diag([sigma**2] * 3 + [1e-10] * 3), (6, 1, 1))
    d = drift_figures(C, Q, x, np.tile(Q, (6, 1)), np.arange(6.0), cov)
    assert d.dap_p == pytest.approx(5e-6, abs=1e-12) and d.drp_l == pytest.approx(0.0)
    one, two = (pose_figure_uncertainty(C, x[i], cov[i, :3, :3]) for i in ([0, 1], [4, 5]))
    assert d.u_dap_p == pytest.approx(math.hypot(one.ap_p, two.ap_p), rel=1e-12)
    assert d.u_drp_l == pytest.approx(one.rp_l + two.rp_l, rel=0.03)
    cov[0, 0, 0] = math.nan
    blind = json.loads(json.dumps(drift_figures(C, Q, x, np.tile(Q, (6, 1)), np.arange(6.0),
                                                cov).to_dict()))
    assert blind['u_dap_p'] is None and blind['dap_p'] == pytest.approx(5e-6)
    assert blind['first']['n'] == 2


@pytest.mark.parametrize(('n', 'times', 'covariance', 'words'), [
    (5, np.arange(5.0), None, 'at least 6 visits'),
    (6, [0.0, 1, 2, 3, 4, math.nan], None, 'finite stamps'),
    (6, np.arange(7.0), None, 'finite stamps'),
    (6, np.arange(6.0), np.zeros((6, 3, 3)), 'expected shape'),
])
def test_bad_input_is_refused(n: int, times: list[float], covariance: np.ndarray | None,
                              words: str) -> None:
    with pytest.raises(InputError, match=words):
        drift_figures(C, Q, np.tile(C, (n, 1)), np.tile(Q, (n, 1)), times, covariance)


@pytest.mark.parametrize(('common', 'noise'), [
    (4e-6, 3e-6),  # a registration error shared by every visit
    (0.0, 5e-6),  # independent errors only: the quadrature of dAP's U is tight here
])
def test_the_true_drift_lies_within_u_of_the_measured_one_in_95_percent_of_runs(
        common: float, noise: float) -> None:
    """200 seeded runs of 12 visits: the machine drifts linearly by up to 20 µm and 50 µrad
    per axis over the run, scatters by 2 µm and 5 µrad per visit; measured with an error
    ``common`` to the run (µrad: 2.5 × the µm) and ``noise`` per visit, each visit stated
    with the sum of both covariances."""
    runs, n = 200, 12
    covered = np.zeros((runs, len(FIGURES)), dtype=bool)
    common_v, noise_v = (np.array([s] * 3 + [2.5 * s] * 3) for s in (common, noise))
    cov = np.tile(np.diag(common_v**2 + noise_v**2), (n, 1, 1))
    t = np.arange(n, dtype=float)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        drift = np.outer(t / (n - 1), rng.uniform(-1, 1, 6) * ([20e-6] * 3 + [50e-6] * 3))
        true = (rng.normal(0.0, [30e-6] * 3 + [100e-6] * 3) + drift
                + rng.normal(0.0, [2e-6] * 3 + [5e-6] * 3, (n, 6)))
        measured = true + rng.normal(0.0, common_v) + rng.normal(0.0, noise_v, (n, 6))

        def pose(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return C + e[:, :3], Rotation.from_rotvec(e[:, 3:]).as_quat()

        d_true = drift_figures(C, Q, *pose(true), t)
        d_measured = drift_figures(C, Q, *pose(measured), t, cov)
        for i, name in enumerate(FIGURES):
            value, u = d_measured.figure(name)
            truth, _ = d_true.figure(name)
            covered[seed, i] = abs(value - truth) <= u
    share = covered.mean(axis=0)
    print(dict(zip(FIGURES, np.round(share, 3), strict=True)))
    assert np.all(share >= 0.95), share
