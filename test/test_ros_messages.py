"""The ROS adapter's message helpers that need no DDS."""

from __future__ import annotations

import time

from positioning_cell.ros.messages import published_monotonic


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
