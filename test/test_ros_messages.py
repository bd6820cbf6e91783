"""The ROS adapter's message helpers that need no DDS."""

from __future__ import annotations

import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from positioning_cell.errors import InputError
from positioning_cell.ros.messages import published_monotonic, registration, registration_msg


def test_publication_time_is_the_receipt_less_the_message_age() -> None:
    before = time.monotonic()
    age_s = 0.25
    published = published_monotonic({'source_timestamp': time.time_ns() - round(age_s * 1e9)})
    after = time.monotonic()
    assert before - age_s - 0.05 <= published <= after - age_s + 1e-3


def test_without_a_source_timestamp_or_with_a_future_one_the_receipt_time() -> None:
    for info in ({}, {'source_timestamp': 0}, {'source_timestamp': time.time_ns() + 10**9}):
        before = time.monotonic()
        published = published_monotonic(info)
        assert before <= published <= time.monotonic()


def test_the_registration_survives_its_message_and_a_bad_one_is_refused() -> None:
    """/metrology/registration: the tracker's origin and the covariance of its pose come back
    as sent; a NaN, an asymmetric covariance or a negative variance is refused by name."""
    rng = np.random.default_rng(3)
    a = rng.standard_normal((6, 6)) * np.r_[[5e-6] * 3, [4e-6] * 3]
    cov = a @ a.T
    position = np.array([0.8, 0.3, 2.2])
    msg = registration_msg(position, [0.0, 0.0, 0.0, 1.0], cov, Time(sec=5))
    assert msg.header.frame_id == 'base'
    out = registration(msg)
    np.testing.assert_allclose(out.position, position, rtol=0, atol=0)
    np.testing.assert_allclose(out.covariance, cov, rtol=0, atol=0)
    for bad in (np.full((6, 6), np.nan), cov + np.triu(np.full((6, 6), 1e-9), 1),
                cov - np.diag([1.0] + [0.0] * 5)):
        with pytest.raises(InputError, match='tracker registration'):
            registration(registration_msg(position, [0.0, 0.0, 0.0, 1.0], bad, Time()))
