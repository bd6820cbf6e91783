"""A stream's silence as the positioner's looks show it (positioning_cell.motion.hearing)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from positioning_cell.motion.hearing import Hearing


def test_never_heard_is_an_endless_silence() -> None:
    hearing = Hearing()
    hearing.look(1.0, False)
    assert math.isinf(hearing.silence())


def test_a_stream_that_stops_is_silent_from_the_last_look_that_heard_it() -> None:
    hearing = Hearing()
    for t in (0.0, 0.02, 0.04):
        hearing.look(t, True)
    for t in (0.06, 0.08, 0.30):
        hearing.look(t, False)
    assert math.isclose(hearing.silence(), 0.26)


def test_time_nobody_looked_is_no_silence_until_a_look_finds_nothing() -> None:
    """Heard at 1.0, then nobody looked for 0.5 s (the process held up): no silence shown;
    the next look finds the stream (0), or finds nothing, and then the gap counts."""
    hearing = Hearing()
    hearing.look(1.0, True)
    assert hearing.silence() == 0.0
    hearing.look(1.5, True)
    assert hearing.silence() == 0.0
    hearing.look(2.0, False)
    assert math.isclose(hearing.silence(), 0.5)


@given(st.lists(st.tuples(st.floats(0.0, 100.0), st.booleans()), min_size=1, max_size=30),
       st.randoms(use_true_random=False))
def test_looks_recorded_in_any_order_give_the_same_silence(
        looks: list[tuple[float, bool]], rng: object) -> None:
    """Threads record their looks out of order: the silence depends on the looks only."""
    shuffled = list(looks)
    rng.shuffle(shuffled)  # type: ignore[attr-defined]
    a, b = Hearing(), Hearing()
    for t, found in looks:
        a.look(t, found)
    for t, found in shuffled:
        b.look(t, found)
    assert a.silence() == b.silence()
    heard = [t for t, found in looks if found]
    missed = [t for t, found in looks if not found]
    expected = (math.inf if not heard else
                max(0.0, max(missed, default=-math.inf) - max(heard)))
    assert a.silence() == expected
