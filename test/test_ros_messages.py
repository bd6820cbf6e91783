"""The ROS adapter's message helpers that need no DDS."""

from __future__ import annotations

import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from positioning_cell.accuracy import stamp_seconds
from positioning_cell.errors import InputError
from positioning_cell.ros.messages import (
    pose_arrays,
    pose_batches,
    pose_stamped,
    pose_with_covariance,
    published_monotonic,
    registration,
    registration_msg,
)


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


def test_pose_batches_keep_every_field_rank_across_topics_and_stamp_in_rank_order() -> None:
    """The accuracy monitor's streams taken together: each topic's messages in their order,
    ranked after the topic before, each field as the message holds it (the per-message
    conversions as reference), the covariance only where the message states one."""
    rng = np.random.default_rng(5)

    def values(k: int) -> tuple[np.ndarray, np.ndarray, Time]:
        q = rng.standard_normal(4)
        return (rng.standard_normal(3), q / np.linalg.norm(q),
                Time(sec=100 + k, nanosec=int(rng.integers(0, 10**9))))

    readings = []
    for k in range(3):
        position, quaternion, stamp = values(k)
        readings.append(pose_with_covariance(position, quaternion,
                                             rng.standard_normal(36), stamp))
    truths = [pose_stamped(*values(k)) for k in range(4)]
    batches, stamps = pose_batches({'measured': readings, 'truth': truths, 'targets': []})
    assert [b.count for b in batches.values()] == [3, 4, 0]
    assert batches['measured'].rank.tolist() == [0, 1, 2]
    assert batches['truth'].rank.tolist() == [3, 4, 5, 6]
    assert stamps == [msg.header.stamp for msg in readings + truths]
    for key, msgs in (('measured', readings), ('truth', truths)):
        got = batches[key]
        for row, msg in enumerate(msgs):
            pose = getattr(msg.pose, 'pose', msg.pose)
            position, quaternion = pose_arrays(pose)
            np.testing.assert_array_equal(got.position[row], position)
            np.testing.assert_array_equal(got.quaternion[row], quaternion)
            assert got.stamp[row] == stamp_seconds(msg.header.stamp.sec,
                                                   msg.header.stamp.nanosec)
            assert got.frame[row] == msg.header.frame_id
    np.testing.assert_array_equal(batches['measured'].covariance,
                                  np.array([msg.pose.covariance for msg in readings]
                                           ).reshape(3, 6, 6))
    assert batches['truth'].covariance is None
