"""Moving the panel with every positioner as one (issue 27, item 3): the coordinator's rules,
without ROS (the ``cell_coordinator`` node runs them on the node sets,
:mod:`positioning_cell.ros.set_port`).

A panel move (:meth:`Coordinator.move`):

1. the panel's goal (cell frame) becomes each positioner's platform goal in its base
   (:func:`~positioning_cell.coordinated.panel_motion.platform_goals`);
2. every positioner checks its goal in all its limit layers and its state (CheckPose) before
   any moves: one refusal refuses the panel move, naming each positioner that refuses and
   why; nothing moved;
3. one time base (:class:`~positioning_cell.moves.timing.Timing`): every positioner's least
   duration on the coordinated time law (one shape for all: the platforms stay in proportion
   along the way, as the rigid panel moves them), the longest for all, and one start
   ``start_lead`` s ahead, so that the drives start together and reach their goals together;
   one path: each positioner's move carries the panel's origin (its ``pivot``, in its platform
   frame) on a straight line, the platform turning about it, so that every platform follows
   the rigid panel's motion (each on its own straight line and SLERP would leave the chord of
   its arc between them: ~15 µm for a 10 mrad turn 1.2 m from the pivot);
4. every positioner is sent its move; the coordinator watches them every ``poll_period``
   s. A positioner that ends otherwise than settled (refused, aborted, out of tolerance,
   stopped by anyone) stops all the others at once: the panel move ends with its code and
   reason, naming it. A stop asked of the coordinator stops all (ABORTED_STOP); a move not
   over ``end_margin`` s after the common motion's end stops all (ABORTED_TIMEOUT). With a
   :class:`~positioning_cell.coordinated.force_watch.ForceWatch`, an internal force in the
   panel above the cell's limit stops all (ABORTED_INTERNAL_FORCE, naming the pair of
   attachments that disagree). Those three stop every positioner along its path, as one
   (:meth:`Coordinator.stop_all`); after one positioner has ended, the others stop at once.
5. Settled: the panel pose each positioner's attained platform implies, their mean, and how
   far each pair of attachment points is pulled apart
   (:func:`~positioning_cell.coordinated.panel_motion.pair_disagreement`).

Relax (:meth:`Coordinator.relax`, the compliant adjustment of the redundant inputs): at rest,
each positioner's platform as its tracker measures it (the watch's recent readings, averaged)
implies a panel pose; their mean is the rigid placement nearest to where the panel is. Each
positioner is moved, all as one, by what separates its measured platform from that placement
(the non-rigid part of their disagreement: what loads the panel), and keeps that as its
correction, added to its goals from then on (and taken off its plans by the watch). The
panel itself stays where it is, within the readings' noise; its internal force goes. The
watch is off during a relax move: its reference is the commanded panel's placement, which a
relax move leaves on purpose (the move only lowers the disagreement, by tens of µm).

Relax from the load cells (:meth:`Coordinator.relax_forces`): a strain the trackers cannot
see (a socket off its place in the panel: every platform where it is sent, the panel pulled
all the same) is in the legs' forces. At rest, each set's encoders and load cells averaged
give its attachment's force on the panel (:func:`~.load_cells.attachment_forces`); the cell
file's stiffness turns what is internal in them into each positioner's relaxing step
(:func:`~.load_cells.relaxing_steps`), all moved as one, and the steps are kept as its load
correction, added to its goals from then on. A real panel is not as stiff as its file: a
step leaves that error's share of the force, and the relax measures again and steps again
(at most ``passes`` moves) until the largest internal force is at most ``enough`` N; it says
what the load cells gave before and after each move, and, when ``passes`` were not enough,
that the cell file's stiffness falls short. The load corrections are not the trackers': the
watch does not take them off its plans (the trackers see the platforms where they are
sent), and the trackers' relax aims at the rigid placement moved by them.

The strain as the pose changes (:mod:`~.strain_map`): with a
:class:`~.strain_map.StrainMap`, every rest at which the load cells are read (each pass of a
relax, and after every settled panel move, in the background while the panel rests) adds a
sample; once the samples span the pose, each positioner's load correction follows the panel:
the relax's corrections where they were found, plus the map's change from there to the goal.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.force_watch import Excess, ForceWatch
from positioning_cell.coordinated.load_cells import (
    attachment_forces,
    internal_force_sizes,
    relaxing_steps,
)
from positioning_cell.coordinated.panel_motion import (
    PairDisagreement,
    implied_panels,
    mean_panel,
    pair_disagreement,
    platform_goals,
    platforms_in_panel,
    rigid_placement,
)
from positioning_cell.coordinated.settings import CoordinatorSettings, RelaxSettings
from positioning_cell.coordinated.strain_map import StrainMap, balls_in_base
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.moves.timing import FASTEST_COORDINATED, Timing

FloatArray = NDArray[np.float64]
Pose = tuple[FloatArray, FloatArray]


@dataclass(frozen=True)
class PanelRequest:
    """A panel goal: ``position`` (3,) m and ``quaternion`` (4,) of the panel in the cell
    frame; each positioner's settle ``tolerance`` (m; 0: its configured one) and
    ``speed_scale`` in (0, 1] (0: 1), as in a positioner's MoveCommand."""

    position: FloatArray
    quaternion: FloatArray
    tolerance: float = 0.0
    speed_scale: float = 0.0


class Checked(NamedTuple):
    """A positioner's check of its goal: ``code`` (SUCCESS: it would move), ``reason`` (why
    not), and the planned ``duration`` s."""

    code: ResultCode
    reason: str
    duration: float


class Ended(NamedTuple):
    """How a positioner's move ended: its ``code``, ``reason`` and ``attained`` platform pose
    in its base (None: not known)."""

    code: ResultCode
    reason: str
    attained: Pose | None


class Positioner(Protocol):
    """One positioner as the coordinator drives it (its node set, on ROS)."""

    name: str

    def check(self, goal: Pose, request: PanelRequest, duration: float,
              pivot: FloatArray) -> Checked:
        """Check the move to ``goal`` (platform in base) lasting at least ``duration`` s, its
        ``pivot`` (3,) m (platform frame) on a straight line."""

    def move(self, goal: Pose, request: PanelRequest, timing: Timing, pivot: FloatArray
             ) -> Callable[[], Ended | None]:
        """Send the move (about ``pivot``, as checked); the returned poll gives its end (None
        while it runs)."""

    def stop(self) -> None:
        """Stop whatever the positioner runs, under control."""

    def stop_along(self, start: float, duration: float) -> None:
        """Stop its running move along its path from ``start`` (ROS time s) over ``duration``
        s (:mod:`positioning_cell.moves.stopping`; nothing running or too late: at once)."""

    def load_cells(self, seconds: float) -> tuple[FloatArray, FloatArray] | None:
        """Its encoder values (6,) (m, rad) and load-cell efforts (6,) (N, N·m), each the mean
        over ``seconds`` s at rest; None when it gave none."""


@dataclass(frozen=True)
class PanelOutcome:
    """How a panel move ended: ``code`` and ``reason`` (naming the positioner that ended it
    otherwise than settled), each positioner's :class:`Ended` (``ends``, by name; those not
    sent a move are missing), the common ``timing``, and when settled the mean ``panel`` pose
    (cell frame) the positioners' attained poses imply and each pair's
    :class:`~positioning_cell.coordinated.panel_motion.PairDisagreement`."""

    code: ResultCode
    reason: str
    ends: dict[str, Ended] = field(default_factory=dict)
    timing: Timing | None = None
    panel: Transform | None = None
    pairs: tuple[PairDisagreement, ...] = ()
    excess: Excess | None = None
    #: The largest internal force the watch estimated during the move: (pair, N).
    peak: tuple[tuple[str, ...], float] | None = None

    @property
    def worst_pair(self) -> PairDisagreement | None:
        """The pair pulled apart (or together) most; None when not known."""
        return max(self.pairs, key=lambda d: abs(d.stretch)) if self.pairs else None


class Coordinator:
    """The coordinator's rules (module docstring) over ``positioners`` (one per positioner of
    ``cell``, in its order) whose model machine is ``mech``; ``clock()`` is ROS time, s;
    ``watch``: the internal force watch its caller feeds (None: not watched); ``strain``: the
    strain map (module docstring; kept by the caller across cell files, as its samples are the
    machine's, not the file's)."""

    def __init__(self, cell: CellFile, mech: Mechanism, positioners: Sequence[Positioner],
                 settings: CoordinatorSettings | None = None,
                 clock: Callable[[], float] = time.time, watch: ForceWatch | None = None,
                 relax: RelaxSettings | None = None, strain: StrainMap | None = None) -> None:
        if [p.name for p in positioners] != [e.name for e in cell.positioners]:
            raise InputError(f'positioners {[p.name for p in positioners]} are not the '
                             f"cell's {[e.name for e in cell.positioners]}")
        self.cell, self.mech, self.positioners = cell, mech, list(positioners)
        self.settings, self.clock = settings or CoordinatorSettings(), clock
        self.watch, self.relax_settings = watch, relax or RelaxSettings()
        #: Each positioner's correction (m, its base frame) from :meth:`relax`: added to its
        #: platform goals.
        self.corrections = {e.name: np.zeros(3) for e in cell.positioners}
        #: Each positioner's load correction (m, its base frame) from :meth:`relax_forces`:
        #: added to its platform goals too.
        self.load_corrections = {e.name: np.zeros(3) for e in cell.positioners}
        #: The panel's last goal (cell frame): home until a move settles.
        self.panel_goal = Transform.identity()
        #: The strain map its rests feed (module docstring; None: the load corrections are one
        #: for every pose), and the panel pose at which the load corrections were found.
        self.strain, self.load_pose = strain, Transform.identity()
        #: The platform goals last sent and settled (each in its base), and the common start
        #: of the last panel move (ROS time s): a rest's reading is a sample only if no
        #: motion began before it ended.
        self._sent: list[Pose] | None = None
        self._last_start = float('-inf')
        #: Held while the load cells are read (one reading at a time).
        self._reading = threading.Lock()
        #: Each positioner's pivot (3,) m: the panel's origin in its platform frame, the one
        #: point of the panel every platform's motion carries on a straight line (so that
        #: they move as the rigid panel; moves.trajectory).
        self.pivots = [held.inverse().p for held in platforms_in_panel(cell, mech)]
        #: The common time base of the panel move running (None: none runs).
        self._timing: Timing | None = None

    def stop_all(self, along: bool = True) -> None:
        """Stop every positioner: each asked at once, in a thread of its own, whatever the
        others answer (RuntimeError naming those that could not be asked). While a panel move
        runs and ``along``, along its path (:mod:`positioning_cell.moves.stopping`): every
        positioner from one instant ``stop_lead`` s ahead, at rest within ``stop_time`` s or
        the move's own ramp (a quarter of its duration) when shorter, so that the platforms
        stay where the rigid panel puts them (each drive's own stop, from when the stop
        reaches it, leaves them apart: test_stopping); one that cannot be asked so is stopped
        at once. Not ``along``: all at once (one positioner has stopped on its own already:
        the others would run on past it)."""
        errors: list[str] = []
        timing, s = self._timing if along else None, self.settings
        start = self.clock() + s.stop_lead
        duration = min(s.stop_time, timing.duration / 4.0) if timing is not None else 0.0

        def stop(p: Positioner) -> None:
            try:
                if duration > 0.0:
                    try:
                        p.stop_along(start, duration)
                        return
                    except Exception:  # not asked so: stopped at once instead, below
                        pass
                p.stop()
            except Exception as err:  # the others must be stopped all the same
                errors.append(f'{p.name}: {err}')

        self._each(stop)
        if errors:
            raise RuntimeError('stop not delivered to ' + '; '.join(errors))

    def _each(self, work: Callable[[Positioner], None]) -> None:
        """``work`` done for every positioner at once, each in a thread of its own; returns
        when all are done."""
        threads = [threading.Thread(target=work, args=(p,), daemon=True)
                   for p in self.positioners]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    def move(self, request: PanelRequest, stop: threading.Event,
             progress: Callable[[float], None] | None = None) -> PanelOutcome:
        """Move the panel (module docstring); ``stop`` set: stop every positioner and end;
        ``progress(share)`` with the share of the common motion's time elapsed."""
        try:
            goals = self._corrected(Transform.from_pq(request.position, request.quaternion))
        except InputError as err:
            return PanelOutcome(ResultCode.REFUSED_INVALID_GOAL, f'panel goal: {err}')
        outcome = self._run(goals, request, stop, progress)
        if outcome.code is ResultCode.SUCCESS:
            self.panel_goal = Transform.from_pq(request.position, request.quaternion)
            if self.strain is not None:  # read while the panel rests, taking no time here
                threading.Thread(target=self._sample_rest, daemon=True).start()
        return outcome

    def _corrected(self, panel: Transform) -> list[Pose]:
        """Each positioner's platform goal for the panel at ``panel``, with its corrections."""
        goals = platform_goals(self.cell, self.mech, *panel.to_pq())
        return [(p + self.corrections[e.name] + load, q) for (p, q), e, load
                in zip(goals, self.cell.positioners, self._load_side(panel), strict=True)]

    def _load_side(self, panel: Transform) -> list[FloatArray]:
        """Each positioner's load correction (3,) m, its base frame, for the panel at
        ``panel``: as the relax found it, moved by the strain map from where it was found
        when the map spans the pose (module docstring)."""
        fit = self.strain.fit(self.cell, self.mech) if self.strain is not None else None
        follow = fit.changes(panel, self.load_pose) if fit is not None \
            else np.zeros((len(self.cell.positioners), 3))
        return [self.load_corrections[e.name] + f
                for e, f in zip(self.cell.positioners, follow, strict=True)]

    def _learn(self, forces: FloatArray, sent: list[Pose] | None) -> None:
        """A sample of the strain map from the load cells' ``forces`` (N_sets, 3) N at rest
        with the platforms at the goals ``sent``."""
        if self.strain is None or sent is None:
            return
        steps = relaxing_steps(self.cell, self.mech, forces)
        self.strain.add(balls_in_base(self.cell, sent, steps), steps)

    def _sample_rest(self) -> None:
        """After a settled panel move: the load cells read at rest, a sample unless a set gave
        none or a next move's motion began before the reading ended."""
        sent, start_before = self._sent, self._last_start
        if self._reading.locked():  # a reading under way already (a relax's): no sample
            return
        forces = self._load_cell_forces()
        # a next goal sent meanwhile is fine: its motion starts start_lead later
        moved = self._last_start != start_before and self._last_start <= self.clock()
        if not isinstance(forces, str) and sent is not None and not moved:
            self._learn(forces, sent)

    def relax(self, stop: threading.Event, readings: int = 10) -> PanelOutcome:
        """Relax the panel (module docstring) from the mean of each positioner's last
        ``readings`` tracker readings; refused (nothing moves) without a watch or without
        those readings."""
        if self.watch is None:
            return PanelOutcome(ResultCode.REFUSED_INVALID_GOAL, 'no force watch: the '
                                'positioners\' readings are not followed')
        measured = {e.name: self.watch.rest_pose(e.name, readings)
                    for e in self.cell.positioners}
        missing = [n for n, pose in measured.items() if pose is None]
        if missing:
            return PanelOutcome(ResultCode.REFUSED_TRACKER_SILENT, f'refused, nothing moved: '
                                f'fewer than {readings} recent tracker readings of '
                                f'{", ".join(missing)}')
        poses = [pose for pose in measured.values() if pose is not None]
        placed = rigid_placement(self.cell, self.mech, poses)
        steps = [target[0] + load - pose[0] for target, pose, load
                 in zip(placed, poses, self._load_side(self.panel_goal), strict=True)]
        outcome = self._step(steps, stop, self.corrections)
        if outcome.code is not ResultCode.SUCCESS:
            return outcome
        moved = ', '.join(f'{e.name} {np.linalg.norm(d) * 1e6:.1f} um'
                          for e, d in zip(self.cell.positioners, steps, strict=True))
        return dataclasses.replace(outcome, reason=f'relaxed: moved {moved}; {outcome.reason}')

    def _step(self, steps: Sequence[FloatArray] | FloatArray, stop: threading.Event,
              kept: dict[str, FloatArray]) -> PanelOutcome:
        """A relax move: every positioner, at rest, moved as one by its step (``steps``, one
        (3,) m per positioner, its base frame) from where the panel's goal puts it,
        unwatched (module docstring); once settled, each step added to its correction in
        ``kept``."""
        goals = [(c[0] + d, c[1]) for c, d in zip(self._corrected(self.panel_goal), steps,
                                                  strict=True)]
        outcome = self._run(goals, PanelRequest(*self.panel_goal.to_pq()), stop, None,
                            watched=False)
        if outcome.code is ResultCode.SUCCESS:
            for e, d in zip(self.cell.positioners, steps, strict=True):
                kept[e.name] = kept[e.name] + d
        return outcome

    def _load_cell_forces(self) -> FloatArray | str:
        """Each attachment's force on the panel (N_sets, 3) N, cell frame, from the sets' load
        cells at rest (module docstring); a reason when a set gave none or they give none."""
        window = self.relax_settings.window
        # one set after the other, under one lock: reading the sets at once from several
        # threads (each read subscribes and unsubscribes on the client's node) left the
        # coordinator's participant unseen by participants that joined later, in two CIs
        with self._reading:
            readings = [(p.name, self._read(p, window)) for p in self.positioners]
        silent = [name for name, r in readings if r is None]
        if silent:
            return f'no load-cell readings of {", ".join(silent)} in {window:g} s'
        joints = np.array([r[0] for _, r in readings if r is not None])
        efforts = np.array([r[1] for _, r in readings if r is not None])
        try:
            return attachment_forces(self.cell, self.mech, joints, efforts)
        except InputError as err:
            return f'the load cells give no forces: {err}'

    @staticmethod
    def _read(p: Positioner, window: float) -> tuple[FloatArray, FloatArray] | None:
        """``p``'s load cells over ``window`` s; None when it gave none or could not be read
        (said as silent)."""
        try:
            return p.load_cells(window)
        except Exception:  # not read: silent
            return None

    def _largest(self, forces: FloatArray) -> float:
        """The largest internal force at one attachment, N, in ``forces`` (N_sets, 3) N."""
        return float(internal_force_sizes(self.cell, self.mech, forces).max())

    def relax_forces(self, stop: threading.Event) -> PanelOutcome:
        """Relax the panel from its load cells (module docstring); refused, no relaxing move,
        when a set's load cells are silent. The panel is first put at its goal as the cell now
        commands it (a watched panel move: after a new cell file the platforms still stand
        where the old one put them, and a relax there would read the strain of a placement
        the next move leaves). Its reason gives the largest internal force the load cells
        gave before each relaxing move and after the last."""
        # the load corrections from here on are found at this pose (what the map moved them
        # by on the way here, kept)
        here = self._load_side(self.panel_goal)
        self.load_corrections = {e.name: c for e, c in zip(self.cell.positioners, here,
                                                            strict=True)}
        self.load_pose = self.panel_goal
        placed = self._run(self._corrected(self.panel_goal),
                           PanelRequest(*self.panel_goal.to_pq()), stop, None)
        if placed.code is not ResultCode.SUCCESS:
            return placed
        forces = self._load_cell_forces()
        if isinstance(forces, str):
            return PanelOutcome(ResultCode.REFUSED_DRIVER_SILENT, f'refused, no relaxing move: '
                                f'{forces}')
        self._learn(forces, self._sent)
        settings, seen = self.relax_settings, [self._largest(forces)]
        outcome = placed
        while seen[-1] > settings.enough and len(seen) <= settings.passes:
            outcome = self._step(relaxing_steps(self.cell, self.mech, forces), stop,
                                 self.load_corrections)
            if outcome.code is not ResultCode.SUCCESS:
                return outcome
            forces = self._load_cell_forces()
            if isinstance(forces, str):
                return PanelOutcome(ResultCode.ABORTED_DRIVER_LOST, f'after {len(seen)} '
                                    f'relaxing moves: {forces}')
            self._learn(forces, self._sent)
            seen.append(self._largest(forces))
        trail = ' -> '.join(f'{f:.0f}' for f in seen)
        moves = len(seen) - 1
        if seen[-1] > settings.enough:
            return PanelOutcome(ResultCode.ABORTED_INTERNAL_FORCE, f'internal force {trail} N '
                                f'in {moves} relaxing moves, still over {settings.enough:g} N: '
                                "the cell file's panel stiffness falls short of the panel's; "
                                'the corrections are kept', outcome.ends, outcome.timing,
                                outcome.panel, outcome.pairs)
        kept = ', '.join(f'{e.name} {np.linalg.norm(self.load_corrections[e.name]) * 1e6:.1f} '
                         'um' for e in self.cell.positioners)
        fit = self.strain.fit(self.cell, self.mech) if self.strain is not None else None
        mapped = f'; {fit.words()}' if fit is not None else ''
        return dataclasses.replace(outcome, reason=f'relaxed by the load cells: internal force '
                                   f'{trail} N in {moves} moves; load corrections {kept}'
                                   f'{mapped}; {outcome.reason}')

    def _run(self, goals: list[Pose], request: PanelRequest, stop: threading.Event,
             progress: Callable[[float], None] | None, watched: bool = True) -> PanelOutcome:
        """Check, time and run the positioners' ``goals`` as one (module docstring), the
        internal force watched (``watched``, when there is a watch)."""
        checks = [p.check(goal, request, FASTEST_COORDINATED, pivot)
                  for p, goal, pivot in zip(self.positioners, goals, self.pivots, strict=True)]
        refusing = [(p.name, c) for p, c in zip(self.positioners, checks, strict=True)
                    if c.code is not ResultCode.SUCCESS]
        if refusing:
            return PanelOutcome(refusing[0][1].code, 'refused, nothing moved: ' + '; '.join(
                f'{name}: {c.reason}' for name, c in refusing))
        start = self.clock() + self.settings.start_lead
        timing = Timing(max(c.duration for c in checks), start)
        self._last_start, self._sent = start, None  # where the platforms rest: not known
        watch = self.watch if watched else None
        if watch is not None:
            watch.reset(self.corrections, since=start)
        polls: list[tuple[str, Callable[[], Ended | None]]] = []
        try:
            self._timing = timing
            try:
                for p, goal, pivot in zip(self.positioners, goals, self.pivots, strict=True):
                    polls.append((p.name, p.move(goal, request, timing, pivot)))
            except Exception as err:  # whatever failed, the sent ones must stop
                self.stop_all(along=False)
                return PanelOutcome(ResultCode.ABORTED_FAULT, f'{p.name}: the move could not '
                                    f'be sent ({err}); every positioner stopped', timing=timing)
            outcome = self._watch(polls, timing, stop, progress, watch)
            if outcome.code is ResultCode.SUCCESS:
                self._sent = goals
            return outcome
        finally:
            self._timing = None

    def _watch(self, polls: list[tuple[str, Callable[[], Ended | None]]], timing: Timing,
               stop: threading.Event, progress: Callable[[float], None] | None,
               watch: ForceWatch | None) -> PanelOutcome:
        ends: dict[str, Ended] = {}
        peak: tuple[tuple[str, ...], float] | None = None
        assert timing.start is not None
        deadline = timing.start + timing.duration + self.settings.end_margin
        while True:
            for name, poll in polls:
                if name not in ends:
                    end = poll()
                    if end is not None:
                        ends[name] = end
            failed = [(n, e) for n, e in ends.items() if e.code is not ResultCode.SUCCESS]
            if failed:
                self.stop_all(along=False)
                name, end = failed[0]
                return PanelOutcome(end.code, f'{name}: {end.reason}; every positioner '
                                    'stopped', self._drain(polls, ends), timing)
            sizes = watch.sizes() if watch is not None else None
            if sizes and (peak is None or sizes[0][1] > peak[1]):
                peak = sizes[0]
            excess = watch.excess() if watch is not None else None
            if excess is not None:
                excess = excess._replace(seen=self.clock())
                self.stop_all()
                return PanelOutcome(ResultCode.ABORTED_INTERNAL_FORCE, f'{excess.words()}; '
                                    'every positioner stopped', self._drain(polls, ends), timing,
                                    excess=excess, peak=peak)
            if len(ends) == len(polls):
                return self._settled(ends, timing, peak)
            now = self.clock()
            if stop.is_set():
                self.stop_all()
                return PanelOutcome(ResultCode.ABORTED_STOP, 'stopped: every positioner '
                                    'stopped', self._drain(polls, ends), timing)
            if now > deadline:
                self.stop_all()
                late = [n for n, _ in polls if n not in ends]
                return PanelOutcome(ResultCode.ABORTED_TIMEOUT, f'{", ".join(late)} not '
                                    f'settled {self.settings.end_margin:g} s after the common '
                                    'motion ended; every positioner stopped',
                                    self._drain(polls, ends), timing)
            if progress is not None and timing.duration > 0.0:
                progress(min(max(-timing.delay(now) / timing.duration, 0.0), 1.0))
            stop.wait(self.settings.poll_period)

    def _drain(self, polls: list[tuple[str, Callable[[], Ended | None]]],
               ends: dict[str, Ended], wait: float = 5.0) -> dict[str, Ended]:
        """After a stop: the ends of the stopped moves as they come in (up to ``wait`` s)."""
        deadline = time.monotonic() + wait
        while len(ends) < len(polls) and time.monotonic() < deadline:
            for name, poll in polls:
                if name not in ends:
                    end = poll()
                    if end is not None:
                        ends[name] = end
            time.sleep(self.settings.poll_period)
        return ends

    def _settled(self, ends: dict[str, Ended], timing: Timing,
                 peak: tuple[tuple[str, ...], float] | None) -> PanelOutcome:
        names = [p.name for p in self.positioners]
        attained = [ends[n].attained for n in names]
        if any(a is None for a in attained):
            unknown = [n for n, a in zip(names, attained, strict=True) if a is None]
            return PanelOutcome(ResultCode.SUCCESS, 'every positioner settled (attained pose '
                                f'not known for {", ".join(unknown)})', ends, timing, peak=peak)
        poses = [a for a in attained if a is not None]
        panel = mean_panel(implied_panels(self.cell, self.mech, poses))
        pairs = tuple(pair_disagreement(self.cell, self.mech, poses))
        worst = PanelOutcome(ResultCode.SUCCESS, '', pairs=pairs).worst_pair
        words = 'every positioner settled'
        if worst is not None:
            words += (f'; attachments {worst.first}-{worst.second} '
                      f'{worst.stretch * 1e6:+.1f} um apart from the rigid panel (the worst '
                      'pair)')
        if peak is not None:
            words += (f'; internal force at most {peak[1]:.0f} N ({"-".join(peak[0])}) during '
                      'the move')
        return PanelOutcome(ResultCode.SUCCESS, words, ends, timing, panel, pairs, peak=peak)
