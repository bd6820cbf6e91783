"""positioning_cell.accuracy.stamp_order: the monitor's inputs released in stamp order, whatever
the order messages of different topics arrived in, however the arrivals are grouped and
whenever the release is asked for; late messages counted. No ROS."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from test_accuracy import _fed, _stream

from positioning_cell import accuracy as acc
from positioning_cell.accuracy.stamp_order import EVENT, HOLD_S, MonitorInputs, StampOrder

Arr = NDArray[np.float64]


def _arrivals(stamps: Arr, streams: NDArray[np.intp], rng: np.random.Generator,
              event_late: float, stream_late: float) -> NDArray[np.intp]:
    """An arrival order of messages stamped ``stamps`` of ``streams``: each comes up to
    ``event_late`` s after its stamp (the first of a stream too), a stream's others up to
    ``stream_late`` s, and a stream's messages in their stamp order."""
    late = np.where(streams == EVENT, rng.uniform(0.0, event_late, stamps.size),
                    rng.uniform(0.0, stream_late, stamps.size))
    arrival = stamps + late
    for k in np.unique(streams[streams != EVENT]):
        mine = np.flatnonzero(streams == k)
        mine = mine[np.argsort(stamps[mine], kind='stable')]
        arrival[mine[0]] = stamps[mine[0]] + rng.uniform(0.0, event_late)
        arrival[mine] = np.maximum.accumulate(arrival[mine])
    return np.argsort(arrival, kind='stable')


def _taken(order: StampOrder, stamps: Arr, streams: NDArray[np.intp], cuts: list[int],
           takes: set[int]) -> NDArray[np.intp]:
    """Arrivals added in the groups ``cuts`` make, taken after the groups in ``takes`` and at
    the end (after a flush)."""
    out = []
    bounds = [0, *sorted({c % (stamps.size + 1) for c in cuts}), stamps.size]
    for g, (a, b) in enumerate(itertools.pairwise(bounds)):
        order.add(stamps[a:b], streams[a:b])
        if g in takes:
            out.append(order.take())
    order.flush()
    out.append(order.take())
    return np.concatenate(out)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.lists(st.integers(0, 400), max_size=8),
       st.sets(st.integers(0, 8)))
def test_the_release_is_the_stamp_order_however_messages_arrive_and_are_grouped(
        seed: int, cuts: list[int], takes: set[int]) -> None:
    """Two streams (20 and 50 Hz) that come up to 1.5 s after their stamps, and events
    within ``hold`` of theirs: released in stamp order, none late, however added and
    taken."""
    rng = np.random.default_rng(seed)
    reading = np.arange(0.0, 8.0, 0.05) + rng.uniform(0, 1e-3)
    truth = np.arange(0.0, 8.0, 0.02) + rng.uniform(0, 1e-3)
    event = np.sort(rng.uniform(0.0, 8.0, 12))
    stamps = np.concatenate([reading, truth, event])
    streams = np.concatenate([np.zeros(reading.size, dtype=np.intp),
                              np.ones(truth.size, dtype=np.intp),
                              np.full(event.size, EVENT, dtype=np.intp)])
    arrival = _arrivals(stamps, streams, rng, 0.9 * HOLD_S, 1.5)
    order = StampOrder()
    taken = _taken(order, stamps[arrival], streams[arrival], cuts, takes)
    assert order.late == 0 and order.held == 0
    assert np.array_equal(np.sort(taken), np.arange(stamps.size))
    released = stamps[arrival][taken]
    assert np.all(np.diff(released) >= 0.0)


def test_a_message_that_comes_after_the_horizon_is_late_and_goes_at_its_arrival() -> None:
    order = StampOrder(hold=0.5)
    order.add([1.0, 2.0, 3.0])  # events: 1.0 and 2.0 out once 3.0 came
    assert order.take().tolist() == [0, 1] and order.held == 1
    order.add([1.5])  # behind the horizon (2.5): late, out at once, after those before it
    assert order.late == 1 and order.late_by == pytest.approx(1.0)
    assert order.take().tolist() == [3]
    order.add([2.9, 4.0])
    assert order.take().tolist() == [4, 2]  # 2.9 before 3.0, then 4.0 waits
    order.flush()
    assert order.take().tolist() == [5] and order.held == 0


def test_a_stream_is_waited_for_until_it_stalls() -> None:
    """A target stamped 1.0 waits for the tracker's reading stamped 1.02 that comes 0.7 s
    late, though messages stamped 0.5 s after it came; once the tracker's newest stamp is
    ``stale`` behind, it is not waited for."""
    order = StampOrder(hold=0.5, stale=2.0)
    order.add([0.95], [0])           # a reading
    order.add([1.0, 1.6, 1.7], [EVENT, 1, 1])  # a target, true poses
    assert order.take().tolist() == [0]  # the reading; the target waits for the tracker
    order.add([1.02], [0])
    assert order.take().tolist() == [1, 4]
    order.add([4.5], [1])  # the tracker silent 3.5 s: not waited for
    assert order.take().tolist() == [2, 3]
    order.add([4.6], [EVENT])
    order.add([5.2], [1])
    assert order.take().tolist() == [5, 6]
    order.add([1.1], [0])  # the stalled tracker again, far behind: late
    assert order.late == 1 and order.take().tolist() == [8]


@pytest.mark.parametrize('hold', [0.0, -1.0, float('nan'), float('inf')])
def test_a_hold_that_is_no_time_is_refused(hold: float) -> None:
    with pytest.raises(ValueError, match='hold must be a finite time > 0 s'):
        StampOrder(hold=hold)


def _jittered(events: list[tuple[str, float, str, Arr, Arr]], seed: int
              ) -> list[tuple[str, float, str, Arr, Arr]]:
    """``events`` (in stamp order) as another reader might receive them: the tracker's
    readings and the true poses up to 1.2 s late (each in order), targets, move ends and
    registrations up to 0.4 s."""
    rng = np.random.default_rng(seed)
    stamps = np.array([e[1] for e in events])
    kinds = [e[0] for e in events]
    streams = np.array([{'measured': 0, 'truth': 1}.get(k, EVENT) for k in kinds],
                       dtype=np.intp)
    return [events[i] for i in _arrivals(stamps, streams, rng, 0.4, 1.2)]


def _clean(events: list[tuple[str, float, str, Arr, Arr]]
           ) -> list[tuple[str, float, str, Arr, Arr]]:
    """:func:`test_accuracy._stream`'s run in stamp order without its reading older than the
    one before it (within a topic the order is the stamps') and no two stamps equal."""
    out: list[tuple[str, float, str, Arr, Arr]] = []
    latest: dict[str, float] = {}
    seen: set[float] = set()
    for i, (kind, stamp, frame, p, q) in enumerate(events):
        if stamp < latest.get(kind, -np.inf):
            continue
        latest[kind] = stamp
        t = stamp + 1e-7 * i if stamp in seen else stamp
        seen.add(t)
        out.append((kind, t, frame, p, q))
    return sorted(out, key=lambda e: e[1])


def _through(events: list[tuple[str, float, str, Arr, Arr]], size: int
             ) -> tuple[acc.Monitor, MonitorInputs]:
    monitor = acc.Monitor()
    inputs = MonitorInputs(monitor)
    for start in range(0, len(events), size):
        inputs.arrive(**_fed(events[start:start + size], start))  # type: ignore[arg-type]
        inputs.release()
    inputs.release(flush=True)
    return monitor, inputs


@functools.cache
def _in_stamp_order(run: int) -> acc.Monitor:
    """The monitor fed :func:`test_accuracy._stream`'s run (:func:`_clean`) one message at a
    time in stamp order."""
    return _through(_clean(_stream(run)), 1)[0]


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 200), st.integers(0, 2))
def test_two_readers_that_received_in_other_orders_give_the_same_figures(
        seed: int, size: int, run: int) -> None:
    """The live monitor and the recorder get the same messages in other orders across topics
    (repairs, the tracker's latency): through MonitorInputs, the same report, verdicts and
    ignored messages as in stamp order, nothing late."""
    reference = _in_stamp_order(run)
    other, inputs = _through(_jittered(_clean(_stream(run)), seed), size)
    assert inputs.order.late == 0
    a, b = reference.report(), other.report()
    assert a['verdicts']['ok'] + a['verdicts']['error'] == 4
    a.pop('tracker'), b.pop('tracker')  # its sums grouped differently: test_accuracy
    assert a == b
    assert reference.verdicts == other.verdicts
    assert sorted(reference.ignored, key=lambda i: i.time) == sorted(other.ignored,
                                                                     key=lambda i: i.time)


def test_in_recorded_order_the_same_run_could_give_other_figures() -> None:
    """The baseline of the test above: the monitor fed in the jittered arrival order itself
    (as before stamp order) does not always give the stamp order's figures."""
    ordered = _clean(_stream(0))
    reference = _in_stamp_order(0)
    differ = 0
    for seed in range(10):
        monitor = acc.Monitor()
        jittered = _jittered(ordered, seed)
        monitor.feed(**_fed(jittered, 0))  # type: ignore[arg-type]
        a, b = reference.report(), monitor.report()
        a.pop('tracker'), b.pop('tracker')
        differ += a != b
    assert differ > 0


def test_what_waits_is_counted_until_it_is_fed() -> None:
    """Arrivals wait (counted in ``held``) until a release feeds them; a flush feeds all."""
    inputs = MonitorInputs(acc.Monitor())
    events = _clean(_stream(0))[:40]
    inputs.arrive(**_fed(events, 0))  # type: ignore[arg-type]
    assert inputs.held == 40 and inputs.to_dict() == {'held': 40, 'late': 0, 'late_by': 0.0}
    released = inputs.release()
    assert released is not None and 0 < inputs.held < 40
    fed = released.targets.count + released.measured.count + released.truth.count \
        + released.registrations.count + released.ends.count
    assert fed == 40 - inputs.held
    inputs.release(flush=True)
    assert inputs.held == 0 and inputs.release() is None
