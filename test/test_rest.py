"""The end of a move's settle dwell (positioning_cell.motion.rest): the encoders must stay
within a fine tolerance of their target for a whole window; a reading outside starts it
again; a window of 0 never ends the dwell early."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from positioning_cell.errors import InputError
from positioning_cell.motion.rest import RestWatch

TARGET = np.array([0.2, 0.2, 0.2, 0.01, -0.02, 0.0])
TOLERANCE = np.array([1.5e-6] * 3 + [1e-5] * 3)


def test_still_for_the_window_is_at_rest_not_before() -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.05)
    assert not watch.reading(TARGET + 1e-6, 1.00)  # within, the window starts
    assert not watch.reading(TARGET - 1e-6, 1.03)
    assert watch.reading(TARGET, 1.05)
    assert watch.at_rest


def test_a_reading_outside_starts_the_window_again() -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.05)
    watch.reading(TARGET, 1.00)
    outside = TARGET.copy()
    outside[4] += 2e-5  # a theta two counts off
    assert not watch.reading(outside, 1.04)
    assert not watch.reading(TARGET, 1.06)
    assert not watch.reading(TARGET, 1.10)
    assert watch.reading(TARGET, 1.11)


def test_an_old_or_repeated_reading_changes_nothing() -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.05)
    watch.reading(TARGET, 1.00)
    assert not watch.reading(TARGET + 1.0, 0.99)  # older than the last: ignored
    assert watch.reading(TARGET, 1.05)
    assert watch.reading(TARGET + 1.0, 1.05)  # not newer: ignored, still at rest


def test_an_unreadable_encoder_is_not_at_rest() -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.05)
    watch.reading(TARGET, 1.00)
    assert not watch.reading(np.full(6, np.nan), 1.06)


@given(st.floats(0.0, 1.0), st.integers(1, 20))
def test_a_window_of_zero_never_ends_the_dwell(start: float, count: int) -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.0)
    for k in range(count):
        assert not watch.reading(TARGET, start + 0.01 * k)


@given(st.floats(0.01, 1.0), st.lists(st.floats(0.0, 0.2), min_size=1, max_size=20))
def test_at_rest_only_after_a_whole_window_within(window: float, gaps: list[float]) -> None:
    """Readings within tolerance at increasing times: at rest exactly when the span since the
    first of them reaches the window."""
    watch = RestWatch(TARGET, TOLERANCE, window)
    times = 1.0 + np.cumsum([0.0, *gaps])
    for t in times:
        assert watch.reading(TARGET, float(t)) is bool(t - times[0] >= window)


@pytest.mark.parametrize(('args', 'words'), [
    ((TARGET, TOLERANCE, -0.1), 'window'),
    ((TARGET, TOLERANCE, float('nan')), 'window'),
    ((TARGET[:5], TOLERANCE, 0.05), 'target'),
    ((TARGET, TOLERANCE[:3], 0.05), 'tolerance'),
])
def test_bad_input_names_the_field(args: tuple[object, object, float], words: str) -> None:
    with pytest.raises(InputError, match=words):
        RestWatch(*args)  # type: ignore[arg-type]


def test_still_from_is_the_stamp_of_the_window_s_first_reading_once_at_rest() -> None:
    watch = RestWatch(TARGET, TOLERANCE, 0.05)
    watch.reading(TARGET + 1e-3, 1.00, 10.00)  # still moving
    watch.reading(TARGET, 1.01, 10.01)  # the still window starts here
    assert np.isnan(watch.still_from)  # not yet at rest
    watch.reading(TARGET, 1.06, 10.06)
    assert watch.at_rest and watch.still_from == 10.01
    unstamped = RestWatch(TARGET, TOLERANCE, 0.05)
    unstamped.reading(TARGET, 1.00)
    assert unstamped.reading(TARGET, 1.05) and np.isnan(unstamped.still_from)
