"""The internal force in the panel while it moves, estimated from what the cell measures (issue
27, item 4): each positioner's tracker readings against where its trajectory commands the
platform at the reading's instant.

For positioner i, a reading at stamp t (its platform pose in its base) puts its attachment
point at a_i(t) (cell frame); its plan (the platform poses of the trajectory it sent its
drives, stamped at their commanded instants, as it publishes it on /positioner/planned_path
with every trajectory; each plan supersedes the earlier ones from its first instant on, and
holds its last pose after it) interpolated at t puts it at c_i(t). Plans, not the setpoints a
positioner publishes as it runs: a stalled positioner (its node starved of the CPU) publishes
no setpoint for 70 ms and more while its drives run on, and the watch held at its last one
read hundreds of newtons where the panel simulator's truth said tens (the shipped cell's run,
issue 27: 824 N fed the true platform poses, the truth 61 N). The platforms are commanded
along the rigid panel's motion (:mod:`.panel_motion`), so what a positioner adds to the panel
is its deviation δ_i = a_i − c_i (with the rotation's, for a clamp). The deviations are compared at
common instants: the last ``smoothing`` readings' stamps of the positioner whose latest
reading is the oldest, every other positioner's deviation interpolated there (linear in time)
and the ``smoothing`` instants averaged (the tracker's noise, ~10 µm per reading, is ~100 N
at 1e7 N/m). Compared at their own instants, the deviations while the panel moves held the
drives' following error (a lag all share, which loads nothing: the lagging platforms are
the rigid panel a little earlier) taken at instants up to a reading period apart, and with
the panel turning, where each platform moves its own way, that difference read as hundreds
of newtons on machines without error. The internal force systems the deviations load follow
from the linear map of seed 002's deformation compatibility
(:func:`.internal_forces.pair_map`), built on the panel at home: each deviation is taken into
the commanded panel's frame (a rigid motion of the panel moved and turned is then a rigid
motion of the map's geometry, and loads nothing). A pair above the cell's
``internal_force_limit`` is an :class:`Excess`, stamped with the newest reading it rests on.
Thread-safe: readings and plans come in from the node's callbacks, the coordinator asks.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.internal_forces import pair_map
from positioning_cell.coordinated.panel_motion import bases, platforms_in_panel
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import interpolated_pose, rotation_vector
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.correction import mean_pose

FloatArray = NDArray[np.float64]
#: Plans kept per positioner (a move, its stop, its corrections: a few a panel move).
PLANS_KEPT = 16
#: Tracker readings kept per positioner for its pose at rest (20 Hz: 5 s).
READINGS_KEPT = 100
#: Deviations kept per positioner, in readings per instant compared: enough that the others'
#: series cover the oldest positioner's latest instants (the trackers are not synchronised).
DEVIATIONS_KEPT_PER_INSTANT = 4
#: A plan is the move's when it begins at most this long before the move's start, s (its
#: first stamp is that start, to the nanosecond of a ROS time).
PLAN_START_TOLERANCE = 1e-3


class Excess(NamedTuple):
    """A pair of attachments (``pair``, names) whose internal force ``force`` N exceeds
    ``limit`` N, from readings up to ``stamp`` (ROS time s); ``seen``: when the coordinator
    acted on it (ROS time s; NaN until then)."""

    pair: tuple[str, ...]
    force: float
    limit: float
    stamp: float
    seen: float = float('nan')

    def words(self) -> str:
        """The excess for people."""
        return (f'internal force {self.force:.0f} N between {" and ".join(self.pair)} above the '
                f'limit {self.limit:.0f} N')


class ForceWatch:
    """The watch of the module docstring over ``cell`` (its panel's stiffness and limit) whose
    positioners' model machine is ``mech``."""

    def __init__(self, cell: CellFile, mech: Mechanism, smoothing: int = 3) -> None:
        if smoothing < 1:
            raise InputError(f'smoothing = {smoothing}: at least one reading')
        self.names = [e.name for e in cell.positioners]
        self.limit = cell.panel.internal_force_limit
        self._bases = dict(zip(self.names, bases(cell), strict=True))
        self._offsets = {e.name: np.asarray(e.offset, dtype=float) for e in cell.positioners}
        self._in_panel = dict(zip(self.names, platforms_in_panel(cell, mech), strict=True))
        self._map = pair_map(cell.attachments(mech), cell.panel.stiffness)
        self._smoothing = smoothing
        self._lock = threading.Lock()
        self._plans: dict[str, deque[tuple[FloatArray, FloatArray, FloatArray]]] = {
            n: deque(maxlen=PLANS_KEPT) for n in self.names}
        self._deviations: dict[str, deque[tuple[float, FloatArray]]] = {}
        self._recent: dict[str, deque[tuple[FloatArray, FloatArray]]] = {
            n: deque(maxlen=READINGS_KEPT) for n in self.names}
        self._corrections = {n: np.zeros(3) for n in self.names}
        self._since = -math.inf
        self.reset()

    def reset(self, corrections: Mapping[str, ArrayLike] | None = None,
              since: float = -math.inf) -> None:
        """Forget every plan and deviation (a new panel move: its plans come once it is sent;
        a move stopped at once leaves its platforms short of its plan); ``corrections`` (m,
        each positioner's base frame): what the coordinator adds to each one's goals beyond
        the rigid panel's placement (:meth:`Coordinator.relax`), taken off its plans;
        ``since``: the move's start (ROS time s), before which no plan of it begins: a plan
        that does is an earlier command's delivered late, and is not taken (the latched
        topic hands its last plan to a subscriber whenever discovery matches it: a homing's,
        taken for a move's, had the watch judge a positioner that had not yet sent its move
        against where it rested)."""
        with self._lock:
            self._since = since
            for plans in self._plans.values():
                plans.clear()
            kept = self._smoothing * DEVIATIONS_KEPT_PER_INSTANT
            self._deviations = {n: deque(maxlen=kept) for n in self.names}
            if corrections is not None:
                self._corrections = {n: np.asarray(corrections[n], dtype=float)
                                     for n in self.names}

    def plan(self, name: str, stamps: ArrayLike, positions: ArrayLike,
             quaternions: ArrayLike) -> None:
        """Positioner ``name``'s plan: its platform poses (in its base; positions (K, 3) m,
        quaternions (K, 4)) commanded at ``stamps`` (K,) s, increasing (module docstring);
        not kept when it begins before the move's start (:meth:`reset`).
        InputError for one that is not (nothing changes)."""
        t = np.asarray(stamps, dtype=float)
        p, q = np.asarray(positions, dtype=float), np.asarray(quaternions, dtype=float)
        if (t.ndim != 1 or t.size == 0 or p.shape != (t.size, 3) or q.shape != (t.size, 4)
                or not (np.isfinite(t).all() and np.isfinite(p).all()
                        and np.isfinite(q).all()) or (np.diff(t) <= 0.0).any()):
            raise InputError(f'{name}: a plan needs K >= 1 increasing finite stamps with a '
                             f'finite pose each, got stamps {t.shape}, positions {p.shape}, '
                             f'quaternions {q.shape}')
        with self._lock:
            if t[0] >= self._since - PLAN_START_TOLERANCE:
                self._plans[name].append((t, p, q))

    def _commanded(self, name: str, stamp: float) -> tuple[FloatArray, FloatArray] | None:
        """The commanded platform pose at ``stamp`` (under the lock): of the latest plan
        begun by then (the one begun last), interpolated (held after its end); None before
        every plan."""
        begun = [plan for plan in self._plans[name] if plan[0][0] <= stamp]
        if not begun:
            return None
        times, positions, quaternions = max(begun, key=lambda plan: plan[0][0])
        return interpolated_pose(times, positions, quaternions, stamp)

    def reading(self, name: str, stamp: float, position: ArrayLike,
                quaternion: ArrayLike) -> None:
        """Positioner ``name``'s tracker reading (platform in its base) at ``stamp`` s; kept
        as its deviation when a plan has begun by its instant."""
        with self._lock:
            self._recent[name].append((np.asarray(position, dtype=float),
                                       np.asarray(quaternion, dtype=float)))
            commanded = self._commanded(name, stamp)
            if commanded is None:
                return
            base, offset = self._bases[name], self._offsets[name]
            measured = base @ Transform.from_pq(position, quaternion)
            wanted = base @ Transform.from_pq(commanded[0] - self._corrections[name],
                                              commanded[1])
            d_p = measured.apply(offset) - wanted.apply(offset)
            # numpy, not scipy: a first use of scipy here would import it under the lock
            # that the coordinator's next move waits for once it has set its start time
            # (a coordinated relax refused, "the start time was 0.060 s ago", in CI)
            d_r = rotation_vector((measured @ wanted.inverse()).q)
            to_panel = (wanted @ self._in_panel[name].inverse()).R.T  # the commanded panel's
            self._deviations[name].append((stamp, np.concatenate([to_panel @ d_p,
                                                                  to_panel @ d_r])))

    def rest_pose(self, name: str, count: int) -> tuple[FloatArray, FloatArray] | None:
        """Positioner ``name``'s platform (in its base) as the mean of its last ``count``
        tracker readings (position m, normalised mean quaternion); None with fewer."""
        with self._lock:
            recent = list(self._recent[name])[-count:]
        if len(recent) < count:
            return None
        return mean_pose([p for p, _ in recent], [q for _, q in recent])

    def sizes(self) -> tuple[tuple[tuple[str, ...], float], ...] | None:
        """Each pair's internal force (N), largest first, from the deviations at the latest
        common instants (module docstring); None until every positioner has one."""
        with self._lock:
            if not all(self._deviations.values()):
                return None
            series = {n: list(self._deviations[n]) for n in self.names}
        oldest = min(self.names, key=lambda n: series[n][-1][0])
        # only instants every series covers: held at a series' first deviation (np.interp's
        # ends), a positioner whose plan began later was compared at another instant, a
        # following error apart while the drives accelerate
        first = max(series[n][0][0] for n in self.names)
        instants = np.array([t for t, _ in series[oldest][-self._smoothing:] if t >= first])
        if instants.size == 0:
            return None
        mean = []
        for name in self.names:
            stamps = np.array([t for t, _ in series[name]])
            values = np.array([d for _, d in series[name]])
            at = np.column_stack([np.interp(instants, stamps, values[:, c]) for c in range(6)])
            mean.append(at.mean(axis=0))
        return self._map.sizes(np.array(mean))

    def excess(self) -> Excess | None:
        """The worst pair when its force exceeds the limit; None otherwise (or not known)."""
        sizes = self.sizes()
        if not sizes or sizes[0][1] <= self.limit:
            return None
        with self._lock:
            stamp = max(d[-1][0] for d in self._deviations.values())
        return Excess(sizes[0][0], sizes[0][1], self.limit, stamp)


def force_watch(cell: CellFile, mech: Mechanism) -> ForceWatch:
    """The :class:`ForceWatch` of ``cell``; ConfigError naming the cell file when its
    attachments do not hold the panel (its internal forces are then not determined: two balls
    leave it a turn about the line through them)."""
    try:
        return ForceWatch(cell, mech)
    except InputError as err:
        raise ConfigError(f'{cell.path}: the internal force of this panel cannot be watched: '
                          f'{err}') from err
