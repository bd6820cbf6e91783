"""The accuracy monitor's inputs put back in header-stamp order before the monitor takes them,
so that its figures do not depend on the order in which messages of different topics arrived.

The monitor's rules (:mod:`positioning_cell.accuracy.settle`) take targets, move ends, the
tracker's readings, the true poses and the tracker's registrations as one sequence. Two
readers of the same topics (the live monitor and the recorder whose bag the offline analysis
replays) do not see messages of *different* topics in the same order: the recorder of
test/data/makerun got the tracker's readings up to 0.68 s after their stamps and the targets
within 0.04 s; rclpy's executor serves a node's ready subscriptions in its own order (a target
taken before readings that came before it: test_accuracy_monitor_node); a reliable message
whose datagram was dropped comes again at its writer's next heartbeat (0.16 s later on the
cell's profile: benchmarks/repair_latency.py). In arrival order a reading taken before a
target could count against that target, and a visit settle on another window than in the
replay of the bag (test_analysis: the make run bag's figures).

So each message is held until the messages stamped before it have surely come: a target,
move end or registration comes at most :data:`HOLD_S` after messages stamped after it, and the
tracker's readings and the true poses (*streams*, in stamp order each) come when they come.
Then it is released with the others in stamp order (:class:`StampOrder`, which has the rule).
The order released is a function of the sequence of arrivals alone (not of when it is asked
for, nor of how the arrivals are grouped), and it is the stamp order whatever the arrival
order unless a message is *late* (released at its arrival's place and counted: the monitor's
report says how many, and its figures may then differ from an offline analysis). The live
node releases everything held once nothing arrived for :data:`HOLD_S` of wall time
(:meth:`StampOrder.flush`), so that the last messages before a pause are taken.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.monitor import Fed, Ignored, Monitor, MoveEnds, PoseMessages
from positioning_cell.accuracy.settle import Visit
from positioning_cell.accuracy.verdicts import Verdict

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: How long (s) a target, move end or registration may come after a message stamped later than
#: it: above the lateness of a dropped and repaired message (0.16 s,
#: benchmarks/repair_latency.py; 0.04 s at most for targets, 0.18 s for the positioner's
#: statuses in test/data/makerun's bag), and no longer than the settle window and dwell the
#: monitor's rules are built on (0.5 s by default). A verdict comes that much after the reading
#: that settled its visit.
HOLD_S = 0.5
#: A stream (the tracker's readings, the true poses) whose newest stamp is this far (s) behind
#: the newest of all inputs is not waited for (stopped, or stalled): what it sends later is
#: late.
STALE_S = 2.0
#: The stream of a message that is no stream (:meth:`StampOrder.add`): a target, a move end, a
#: registration.
EVENT = -1


class StampOrder:
    """Messages numbered in arrival order (0, 1, ...) released in stamp order: :meth:`add` the
    stamps (s) of those that arrived with their streams, :meth:`take` the arrival numbers of
    those released, in the order they are released. ``hold``, ``stale`` (s) > 0.

    A message is released once (a) a message stamped ``hold`` s or more after it has arrived
    (a target, move end or registration comes at most so late) and (b) every *stream* (a
    topic whose messages come in stamp order, e.g. the tracker's readings at 20 Hz) has
    delivered one stamped at or after it, unless that stream's newest stamp is ``stale`` s
    behind the newest of all (the tracker's readings came up to 0.68 s after their stamp in
    test/data/makerun's bag, its targets within 0.04 s: a stream is waited for, not held
    against a fixed time). Released together, messages go in stamp order, then arrival order.
    So the order is a function of the arrivals alone, not of when it is taken nor of how the
    arrivals are grouped; and it is the stamp order when nothing is late: a message is *late*
    when it arrives after messages stamped after it were released (counted in :attr:`late`;
    released at its arrival's place)."""

    def __init__(self, hold: float = HOLD_S, stale: float = STALE_S) -> None:
        for name, value in (('hold', hold), ('stale', stale)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be a finite time > 0 s, got {value!r}')
        self.hold, self.stale = hold, stale
        #: Messages added so far.
        self.arrived = 0
        #: The newest finite stamp added (s; −inf: none), and each stream's.
        self.newest = -math.inf
        self.newest_of: dict[int, float] = {}
        #: Messages stamped up to this (s) are released.
        self.horizon = -math.inf
        #: Messages that came after messages stamped after them were released.
        self.late = 0
        #: The most a late message came behind the horizon then (s; 0: none late).
        self.late_by = 0.0
        self._held = (np.empty(0), np.empty(0, dtype=np.intp))  # stamps, arrival numbers
        # Released, not taken yet: (release point, sort stamp, arrival number) chunks.
        self._ready: list[tuple[IntArray, FloatArray, IntArray]] = []

    @property
    def held(self) -> int:
        """How many messages wait."""
        return int(self._held[1].size)

    def to_dict(self) -> dict[str, float]:
        """``held``, ``late`` and ``late_by`` (s), for a report."""
        return {'held': self.held, 'late': self.late, 'late_by': self.late_by}

    def _horizons(self, s: FloatArray, streams: IntArray, finite: NDArray[np.bool_]
                  ) -> tuple[FloatArray, FloatArray]:
        """The newest stamp and the horizon after each of the arrivals ``s`` (N,) of
        ``streams`` (N,); each stream's newest stamp kept."""
        newest = np.maximum(self.newest,
                            np.maximum.accumulate(np.where(finite, s, -math.inf)))
        waited = np.full(s.size, math.inf)  # the oldest newest stamp of the streams waited for
        for k in sorted(set(self.newest_of) | set(np.unique(streams[streams != EVENT]).tolist())):
            mine = np.where((streams == k) & finite, s, -math.inf)
            newest_k = np.maximum(self.newest_of.get(k, -math.inf), np.maximum.accumulate(mine))
            live = np.isfinite(newest_k) & (newest_k >= newest - self.stale)
            waited = np.where(live, np.minimum(waited, newest_k), waited)
            if np.isfinite(newest_k[-1]):
                self.newest_of[k] = float(newest_k[-1])
        horizon = np.maximum.accumulate(np.maximum(
            self.horizon, np.minimum(newest - self.hold, waited)))
        return newest, horizon

    def add(self, stamps: ArrayLike, streams: ArrayLike | None = None) -> IntArray:
        """N messages that arrived, in that order, with header ``stamps`` (N,) s, each of a
        stream (``streams`` (N,): a number >= 0 per stream, :data:`EVENT` for a message of no
        stream; None: none of a stream); their arrival numbers. A non-finite stamp is released
        at its arrival (the monitor ignores it with its reason)."""
        s = np.asarray(stamps, dtype=float).reshape(-1)
        n = s.size
        seq = self.arrived + np.arange(n, dtype=np.intp)
        if n == 0:
            return seq
        k = (np.full(n, EVENT, dtype=np.intp) if streams is None
             else np.asarray(streams, dtype=np.intp).reshape(n))
        finite = np.isfinite(s)
        newest, horizon = self._horizons(s, k, finite)
        before = np.concatenate([[self.horizon], horizon[:-1]])
        late = finite & (s <= before)
        if late.any():
            self.late += int(late.sum())
            self.late_by = max(self.late_by, float(np.max(before[late] - s[late])))
        # Each message is released at the first arrival (its own or later) after which the
        # horizon has passed its stamp (the horizon never falls: searchsorted holds).
        own = np.arange(n, dtype=np.intp)
        at = np.where(finite, np.maximum(np.searchsorted(horizon, s, side='left'), own), own)
        held_s, held_seq = self._held
        held_at = np.searchsorted(horizon, held_s, side='left')
        all_at = np.concatenate([held_at, at])
        all_s = np.concatenate([held_s, np.where(finite, s, -math.inf)])
        all_seq = np.concatenate([held_seq, seq])
        out = all_at < n
        if out.any():
            self._ready.append((self.arrived + all_at[out], all_s[out], all_seq[out]))
        self._held = (all_s[~out], all_seq[~out])
        self.arrived += n
        self.newest, self.horizon = float(newest[-1]), float(horizon[-1])
        return seq

    def flush(self) -> None:
        """Release every message held (after all arrived so far): what waits for a later
        message that is not coming (a pause, the end of a recording)."""
        held_s, held_seq = self._held
        if held_seq.size:
            self._ready.append((np.full(held_seq.size, self.arrived, dtype=np.intp), held_s,
                                held_seq))
        self._held = (np.empty(0), np.empty(0, dtype=np.intp))
        self.horizon = max(self.horizon, self.newest)

    def take(self) -> IntArray:
        """The arrival numbers of the messages released since the last take, in release
        order: by release point, then stamp, then arrival."""
        if not self._ready:
            return np.empty(0, dtype=np.intp)
        at, s, seq = (np.concatenate(c) for c in zip(*self._ready, strict=True))
        self._ready = []
        return seq[np.lexsort((seq, s, at))]


@dataclass(frozen=True)
class Released:
    """What :meth:`MonitorInputs.release` fed to the monitor: its answer, and the messages of
    each input in the monitor's order (their ``rank``: the place in the release order of this
    feed) with ``*_seq`` their arrival numbers (as :meth:`MonitorInputs.arrive` returned
    them)."""

    fed: Fed
    targets: PoseMessages
    measured: PoseMessages
    truth: PoseMessages
    registrations: PoseMessages
    ends: MoveEnds
    targets_seq: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    measured_seq: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    truth_seq: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    registrations_seq: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    ends_seq: IntArray = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    #: The messages of this feed the monitor ignored, with their reasons, in its order.
    ignored: tuple[Ignored, ...] = ()
    #: The tags given with the messages fed (:meth:`MonitorInputs.arrive`), by arrival number.
    tags: dict[int, object] = field(default_factory=dict)

    def said(self) -> list[Said]:
        """What the monitor said of the messages fed, in its order: each reading taken (its
        errors against the target, none before the first; the verdict of a visit it settled)
        and each target that closed a visit (that visit's verdict)."""
        fed = self.fed
        samples = fed.measured.samples
        verdicts, visits = dict(fed.measured.verdicts), dict(samples.visits)
        out = [(int(self.targets.rank[k]), Said(int(self.targets_seq[k]), None, None, visit,
                                                verdict, self.tags.get(int(self.targets_seq[k]))))
               for k, visit, verdict in fed.closed]
        for r in np.flatnonzero(samples.accepted):  # the readings taken: those published
            row = int(r)
            p, rv = samples.position_error[row], samples.orientation_error[row]
            known = bool(np.all(np.isfinite(p)) and np.all(np.isfinite(rv)))
            seq = int(self.measured_seq[row])
            out.append((int(self.measured.rank[row]),
                        Said(seq, p if known else None, rv if known else None, visits.get(row),
                             verdicts.get(row), self.tags.get(seq))))
        return [s for _, s in sorted(out, key=lambda item: item[0])]


@dataclass(frozen=True)
class Said:
    """What the monitor said of one message (:meth:`Released.said`): ``seq`` its arrival
    number; a reading's position error (3,) m and orientation error (rotation vector (3,) rad)
    against the target in ``base`` (None: no target yet, or a target); the visit it settled or
    closed and that visit's verdict (None: none)."""

    seq: int
    position_error: FloatArray | None
    orientation_error: FloatArray | None
    visit: Visit | None
    verdict: Verdict | None
    #: The tag given with the message (None: none).
    tag: object = None


_KINDS = ('targets', 'measured', 'truth', 'registrations')
#: The inputs that are streams (:class:`StampOrder`): the tracker's readings, the true poses.
_STREAMS = {'measured': 0, 'truth': 1}


def _concat(parts: list[PoseMessages]) -> PoseMessages:
    """Pose messages of one input one after the other (their ranks kept)."""
    if not parts:
        return PoseMessages.empty()
    if len(parts) == 1:
        return parts[0]
    stated = [p.covariance for p in parts if p.count]
    covariance = (np.concatenate([c for c in stated if c is not None])
                  if stated and all(c is not None for c in stated) else None)
    return PoseMessages(np.concatenate([p.rank for p in parts]),
                        np.concatenate([p.stamp for p in parts]),
                        np.concatenate([p.frame for p in parts]),
                        np.concatenate([p.position for p in parts]),
                        np.concatenate([p.quaternion for p in parts]), covariance)


def _rows(messages: PoseMessages, rows: IntArray, rank: IntArray) -> PoseMessages:
    """The ``rows`` of ``messages`` with the ranks ``rank``."""
    return PoseMessages(rank, messages.stamp[rows], messages.frame[rows],
                        messages.position[rows], messages.quaternion[rows],
                        None if messages.covariance is None else messages.covariance[rows])


class MonitorInputs:
    """The monitor's inputs as they arrive (:meth:`arrive`), fed to ``monitor`` in stamp order
    (:class:`StampOrder`) by :meth:`release`: the live node's and the offline replay's way
    in, so that both take them in the same order."""

    def __init__(self, monitor: Monitor, hold: float = HOLD_S, stale: float = STALE_S) -> None:
        self.monitor = monitor
        self.order = StampOrder(hold, stale)
        # Per input, the messages waiting (their rank: the arrival number).
        self._waiting: dict[str, list[PoseMessages]] = {k: [] for k in _KINDS}
        self._ends: list[MoveEnds] = []
        self._tags: dict[int, object] = {}  # by arrival number, until released
        # Arrivals not yet added to the order (stamps, streams): added at the next release,
        # one numpy pass for all (the order does not depend on how arrivals are grouped).
        self._arrivals: list[tuple[FloatArray, IntArray]] = []
        self._numbered = 0  # arrival numbers given so far

    def arrive(self, targets: PoseMessages | None = None, measured: PoseMessages | None = None,
               truth: PoseMessages | None = None, ends: MoveEnds | None = None,
               registrations: PoseMessages | None = None, tags: Sequence[object] = ()
               ) -> IntArray:
        """Messages that arrived together, each input in arrival order and all interleaved by
        their ``rank`` (as :meth:`Monitor.feed` takes them); their arrival numbers, in rank
        order. ``tags``: what the caller keeps with each, in rank order (handed back with what
        the monitor said of it: :attr:`Said.tag`; the live node's header stamps)."""
        given = {'targets': targets, 'measured': measured, 'truth': truth,
                 'registrations': registrations}
        parts = [(k, v) for k, v in given.items() if v is not None and v.count]
        end_part = ends if ends is not None and ends.count else None
        ranks = [v.rank for _, v in parts] + ([end_part.rank] if end_part else [])
        stamps = [v.stamp for _, v in parts] + ([end_part.stamp] if end_part else [])
        streams = [np.full(v.count, _STREAMS.get(k, EVENT), dtype=np.intp) for k, v in parts]
        if not ranks:
            return np.empty(0, dtype=np.intp)
        rank, stamp = np.concatenate(ranks), np.concatenate(stamps)
        stream = np.concatenate([*streams, np.full(end_part.count if end_part else 0, EVENT,
                                                   dtype=np.intp)])
        by_rank = np.argsort(rank, kind='stable')
        seq = np.empty(rank.size, dtype=np.intp)
        seq[by_rank] = self._numbered + np.arange(rank.size, dtype=np.intp)
        self._numbered += rank.size
        self._arrivals.append((stamp[by_rank], stream[by_rank]))
        start = 0
        for kind, v in parts:
            self._waiting[kind].append(replace(v, rank=seq[start:start + v.count]))
            start += v.count
        if end_part is not None:
            self._ends.append(MoveEnds(seq[start:], end_part.stamp))
        self._tags.update(zip(seq[by_rank].tolist(), tags, strict=False))
        return seq[by_rank]

    @property
    def held(self) -> int:
        """How many messages wait (arrived, not fed)."""
        return self.order.held + self._numbered - self.order.arrived

    def to_dict(self) -> dict[str, float]:
        """The order's :meth:`StampOrder.to_dict` with every message waiting counted."""
        return {**self.order.to_dict(), 'held': self.held}

    def release(self, *, flush: bool = False) -> Released | None:
        """Feed the messages released since the last call to the monitor (with ``flush``
        every one held first: :meth:`StampOrder.flush`); None when none was."""
        if self._arrivals:
            stamps, streams = (np.concatenate(c) for c in zip(*self._arrivals, strict=True))
            self._arrivals = []
            self.order.add(stamps, streams)
        if flush:
            self.order.flush()
        taken = self.order.take()
        if taken.size == 0:
            return None
        place = np.argsort(taken)  # by arrival number: each one's place in the release order
        sorted_seq = taken[place]

        def split(seqs: IntArray) -> tuple[NDArray[np.bool_], IntArray]:
            i = np.minimum(np.searchsorted(sorted_seq, seqs), sorted_seq.size - 1)
            out = sorted_seq[i] == seqs
            return out, place[i[out]]

        fed_rows: dict[str, PoseMessages] = {}
        fed_seq: dict[str, IntArray] = {}
        for kind in _KINDS:
            waiting = _concat(self._waiting[kind])
            out, rank = split(waiting.rank)
            rows = np.flatnonzero(out)
            order = np.argsort(rank, kind='stable')
            fed_rows[kind] = _rows(waiting, rows[order], rank[order])
            fed_seq[kind] = waiting.rank[rows[order]]
            keep = np.flatnonzero(~out)
            self._waiting[kind] = [_rows(waiting, keep, waiting.rank[keep])] if keep.size else []
        ends = (MoveEnds(np.concatenate([e.rank for e in self._ends]),
                         np.concatenate([e.stamp for e in self._ends]))
                if self._ends else MoveEnds.empty())
        out, rank = split(ends.rank)
        order = np.argsort(rank, kind='stable')
        fed_ends = MoveEnds(rank[order], ends.stamp[out][order])
        ends_seq = ends.rank[out][order]
        self._ends = [MoveEnds(ends.rank[~out], ends.stamp[~out])] if (~out).any() else []
        count = len(self.monitor.ignored)
        fed = self.monitor.feed(fed_rows['targets'], fed_rows['measured'], fed_rows['truth'],
                                fed_ends, fed_rows['registrations'])
        seqs = np.concatenate([*fed_seq.values(), ends_seq])
        return Released(fed, fed_rows['targets'], fed_rows['measured'], fed_rows['truth'],
                        fed_rows['registrations'], fed_ends, fed_seq['targets'],
                        fed_seq['measured'], fed_seq['truth'], fed_seq['registrations'],
                        ends_seq, tuple(self.monitor.ignored[count:]),
                        {s: self._tags.pop(s, None) for s in seqs.tolist()})
