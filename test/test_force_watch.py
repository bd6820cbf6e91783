"""The coordinated cell's internal force watch (issue 27, item 4), without ROS: tracker
readings against the positioners' plans at their instant, the disagreement they show sized pair by
pair, an excess named and stamped; the coordinator stopping every positioner on it."""

from __future__ import annotations

import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from test_coordinator import FakePositioner

from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.coordinator import Coordinator, PanelRequest
from positioning_cell.coordinated.force_watch import ForceWatch, force_watch
from positioning_cell.coordinated.internal_forces import internal_forces
from positioning_cell.coordinated.panel_motion import pair_disagreement, platform_goals
from positioning_cell.coordinated.settings import CoordinatorSettings
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.moves.outcomes import ResultCode

MECH = Mechanism.default()
CELL = cell_file.load(config_path('three_positioners.yaml'))
HOME_P, HOME_Q = MECH.home_position, MECH.home_quaternion
NAMES = ('p1', 'p2', 'p3')


def path(t: float) -> np.ndarray:
    """A platform position commanded at t s: 10 mm/s up from home."""
    return HOME_P + np.array([0.0, 0.0, 0.01 * t])


def planned(watch: ForceWatch, name: str, times: np.ndarray,
            pose: Callable[[float], tuple[np.ndarray, np.ndarray]], t0: float = 100.0) -> None:
    """Positioner ``name``'s plan: ``pose(t)`` at ``t0`` s + ``times``."""
    poses = [pose(float(t)) for t in times]
    watch.plan(name, t0 + times, [p for p, _ in poses], [q for _, q in poses])


def fed(watch: ForceWatch, off: dict[str, np.ndarray], readings: int = 5,
        t0: float = 100.0) -> None:
    """A plan sampled every 20 ms along :func:`path` for 1 s from ``t0`` s; readings every
    50 ms in between (not at a sample's instant), each positioner's ``off`` its true offset
    from its plan."""
    for name in NAMES:
        planned(watch, name, np.arange(0.0, 1.0, 0.02), lambda t: (path(t), HOME_Q), t0)
        for t in 0.013 + 0.05 * np.arange(readings):
            watch.reading(name, t0 + t, path(t) + off.get(name, 0.0), HOME_Q)


def test_positioners_that_follow_their_plans_load_nothing() -> None:
    watch = ForceWatch(CELL, MECH)
    assert watch.sizes() is None  # no reading yet
    fed(watch, {})
    sizes = watch.sizes()
    assert sizes is not None and max(f for _, f in sizes) < 1e-6
    assert watch.excess() is None


def test_one_positioner_off_by_0_2_mm_along_a_side_is_named_with_its_force() -> None:
    """p2 0.2 mm off along the side p1-p2: 1000 N in p1-p2 (k·d, test_internal_forces' hand
    case), 343 N in each other pair, against the 500 N limit."""
    points = np.array([a.point for a in CELL.attachments(MECH)])
    side = (points[1] - points[0]) / np.linalg.norm(points[1] - points[0])
    watch = ForceWatch(CELL, MECH)
    fed(watch, {'p2': 2e-4 * side})
    excess = watch.excess()
    assert excess is not None
    assert excess.pair == ('p1', 'p2') and excess.force == pytest.approx(1000.0, rel=1e-6)
    assert excess.limit == CELL.panel.internal_force_limit == 500.0
    assert excess.stamp == pytest.approx(100.0 + 0.013 + 0.05 * 4)
    assert excess.words() == 'internal force 1000 N between p1 and p2 above the limit 500 N'


def test_readings_before_the_first_plan_are_not_compared_and_a_reset_forgets() -> None:
    watch = ForceWatch(CELL, MECH)
    for name in NAMES:
        watch.reading(name, 99.0, HOME_P + 0.01, HOME_Q)  # before any plan: skipped
    assert watch.sizes() is None
    fed(watch, {'p3': np.array([0.0, 0.0, 1e-3])})
    assert watch.excess() is None  # a ball raised tilts the panel on three balls: no force
    fed(watch, {'p3': np.array([1e-3, 0.0, 0.0])})
    assert watch.excess() is not None
    watch.reset()
    assert watch.sizes() is None


def test_a_plan_of_an_earlier_command_delivered_after_the_reset_is_not_taken() -> None:
    """The latched plans topic hands a subscriber the last plan whenever discovery matches
    it: a homing's plan arriving after the move's reset. Taken, p1 (not yet sent its move)
    was judged against where it rested and p2, 0.2 mm off, read as an excess before p1 had
    moved; not taken, nothing is judged until each positioner's plan of the move begins."""
    watch = ForceWatch(CELL, MECH)
    watch.reset(since=100.0)  # the move starts at 100 s
    for name in NAMES:  # the homings' plans, ended at rest long before
        watch.plan(name, [50.0, 51.0], [HOME_P, HOME_P], [HOME_Q, HOME_Q])
    off = {'p2': np.array([2e-4, 0.0, 0.0])}
    for t in 99.80 + 0.05 * np.arange(4):  # at rest before the start
        for name in NAMES:
            watch.reading(name, t, HOME_P + off.get(name, 0.0), HOME_Q)
    assert watch.sizes() is None
    fed(watch, off)  # the move's plans (from 100 s) and its readings: judged
    excess = watch.excess()
    assert excess is not None and excess.pair == ('p1', 'p2') and excess.stamp > 100.0
    watch.reset()  # no start given: every plan taken, as before
    watch.plan('p1', [50.0, 51.0], [HOME_P, HOME_P], [HOME_Q, HOME_Q])
    watch.reading('p1', 60.0, HOME_P, HOME_Q)
    assert watch.sizes() is None  # (p2 and p3 not yet)


def test_one_stray_reading_among_three_does_not_trip_the_watch() -> None:
    """Three instants are averaged: a single 0.12 mm outlier weighs 40 um, once the others'
    readings reach its instant (compared at common instants: until then it is not used)."""
    watch = ForceWatch(CELL, MECH)
    fed(watch, {})
    watch.reading('p2', 100.5, path(0.5) + np.array([1.2e-4, 0.0, 0.0]), HOME_Q)
    sizes = watch.sizes()
    assert sizes is not None and sizes[0][1] < 1e-6  # the others have not read 100.5 yet
    for name in ('p1', 'p3'):
        watch.reading(name, 100.5, path(0.5), HOME_Q)
    assert watch.excess() is None
    sizes = watch.sizes()
    assert sizes is not None and 100.0 < sizes[0][1] < CELL.panel.internal_force_limit


def panel_at(cell: cell_file.CellFile, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The panel of ``cell`` turning 8 mrad about z through the centroid while rising 10 mm,
    in 1 s on the coordinated time law (ramps of a quarter each)."""
    u = float(np.clip(t, 0.0, 1.0))
    s = (8.0 / 3.0 * u**2 if u < 0.25 else 1.0 / 6.0 + 4.0 / 3.0 * (u - 0.25) if u < 0.75
         else 1.0 - 8.0 / 3.0 * (1.0 - u)**2)
    rotation = Rotation.from_rotvec([0.0, 0.0, 0.008 * s])
    centre = cell.panel_points(MECH).mean(axis=0)
    return centre + [0.0, 0.0, 0.01 * s] - rotation.apply(centre), rotation.as_quat()


def test_a_plan_covers_every_reading_however_its_positioner_stalls() -> None:
    """A turning, accelerating panel, each positioner's plan published once as its move
    starts (sampled every 10 ms, as the positioners plan), exact platforms read by trackers at
    their own phases: nothing loads the panel, whatever the positioners' nodes do meanwhile
    (setpoints published as they ran went silent for 70 ms in a positioner starved of the
    CPU, and the watch held at the last one read 824 N where the panel simulator said 61 N:
    issue 27's shipped run)."""
    clamped = clamped_cell()
    watch = ForceWatch(clamped, MECH)
    for k, name in enumerate(NAMES):
        planned(watch, name, np.arange(0.0, 1.0, 0.01),
                lambda t, k=k: platform_goals(clamped, MECH, *panel_at(clamped, t))[k])
    worst = 0.0
    for t in np.arange(0.0, 1.0, 0.05):
        for k, name in enumerate(NAMES):
            at = t + 0.004 + 0.017 * k
            watch.reading(name, 100.0 + at,
                          *platform_goals(clamped, MECH, *panel_at(clamped, at))[k])
        sizes = watch.sizes()
        if sizes:
            worst = max(worst, sizes[0][1])
    assert 0.0 < worst < 5.0, worst


def test_a_later_plan_supersedes_from_its_first_instant_and_bad_plans_are_refused() -> None:
    """A stop's plan (from 100.5 s on) replaces its move's from there: readings along the move
    before it and along the stop after it load nothing; a plan that is not one is refused
    and changes nothing."""
    watch = ForceWatch(CELL, MECH)
    for name in NAMES:
        planned(watch, name, np.arange(0.0, 1.0, 0.02), lambda t: (path(t), HOME_Q))
        planned(watch, name, 0.5 + np.arange(0.0, 0.3, 0.02),  # held at 0.55 s of the move
                lambda t: (path(min(t, 0.55)), HOME_Q))
    for t in (0.413, 0.463, 0.513, 0.563, 0.613, 0.663, 0.713):
        for name in NAMES:
            watch.reading(name, 100.0 + t, path(min(t, 0.55)), HOME_Q)
        sizes = watch.sizes()
        assert sizes is not None and sizes[0][1] < 1e-6, (t, sizes)
    for stamps, positions in (([1.0, 1.0], [HOME_P, HOME_P]), ([float('nan')], [HOME_P]),
                              ([1.0], [[0.0, 0.0]])):
        with pytest.raises(InputError, match='p1: a plan needs'):
            watch.plan('p1', stamps, positions, [HOME_Q] * len(stamps))
    watch.reading('p1', 100.763, path(0.55), HOME_Q)
    assert watch.sizes() is not None and watch.sizes()[0][1] < 1e-6  # type: ignore[index]


def test_a_positioner_whose_plan_begins_later_is_compared_only_where_it_is_known() -> None:
    """p3's plan begins 100 ms after the others'. Held at its first deviation for the others'
    earlier instants (np.interp at its ends), its following error at another instant read as
    an internal force; compared only where every series is known, none until then, and
    nothing once it is."""
    clamped = clamped_cell()
    watch = ForceWatch(clamped, MECH)
    for k, name in enumerate(NAMES):
        planned(watch, name, np.arange(0.1 if name == 'p3' else 0.0, 0.4, 0.02),
                lambda t, k=k: platform_goals(clamped, MECH, *panel_at(clamped, t))[k])
    sizes_at = []
    for at in 0.013 + 0.05 * np.arange(7):
        for k, name in enumerate(NAMES):
            # every platform 40 ms behind its plan (a following error all share)
            watch.reading(name, 100.0 + at, *platform_goals(
                clamped, MECH, *panel_at(clamped, at - 0.04))[k])
        sizes_at.append(watch.sizes())
    assert sizes_at[0] is None and sizes_at[1] is None  # p3's readings before its plan
    known = [s[0][1] for s in sizes_at if s]
    assert known and max(known) < 30.0, sizes_at


def test_a_lag_every_drive_shares_loads_nothing_while_the_panel_turns() -> None:
    """Platforms that follow a turning, accelerating panel 40 ms late (the drives' following
    error), read by trackers 17 and 34 ms apart: compared at common instants, in the panel's
    frame, no internal force to speak of."""
    clamped = clamped_cell()

    def panel_at_(t: float) -> tuple[np.ndarray, np.ndarray]:
        return panel_at(clamped, t)

    watch = ForceWatch(clamped, MECH)
    for k, name in enumerate(NAMES):
        planned(watch, name, np.arange(0.0, 1.0, 0.02),
                lambda t, k=k: platform_goals(clamped, MECH, *panel_at_(t))[k])
    for k, name in enumerate(NAMES):
        for t in 0.05 + 0.017 * k + 0.05 * np.arange(5):  # through the first ramp
            watch.reading(name, 100.0 + t,
                          *platform_goals(clamped, MECH, *panel_at_(t - 0.04))[k])
    sizes = watch.sizes()
    # compared at each reading's own instant: 121 N; at common instants ~5 N (the deviation's
    # kink at the ramp's end, between two readings), against ~100 N of the trackers' noise
    assert sizes is not None and sizes[0][1] < 20.0, sizes


def clamped_cell() -> cell_file.CellFile:
    """The shipped cell with every positioner clamping the panel."""
    doc = yaml.safe_load(config_path('three_positioners.yaml').read_text())
    for entry in doc['cell']['positioners']:
        entry['attachment']['kind'] = 'clamp'
    with tempfile.TemporaryDirectory() as tmp:
        path_ = Path(tmp) / 'clamped.yaml'
        path_.write_text(yaml.safe_dump(doc))
        return cell_file.load(path_)


def test_a_turned_clamp_loads_its_pair() -> None:
    """Clamps carry couples: a platform turned 1 mrad off its plan loads the panel."""
    clamped = clamped_cell()
    watch = ForceWatch(clamped, MECH)
    turned = Rotation.from_rotvec([1e-3, 0.0, 0.0]).as_quat()
    for name in NAMES:
        watch.plan(name, [1.0], [HOME_P], [HOME_Q])
        watch.reading(name, 1.5, HOME_P, turned if name == 'p3' else HOME_Q)
    sizes = watch.sizes()
    assert sizes is not None and 'p3' in sizes[0][0] and sizes[0][1] > 100.0


def test_a_panel_the_attachments_do_not_hold_cannot_be_watched(tmp_path: Path) -> None:
    doc = yaml.safe_load(config_path('three_positioners.yaml').read_text())
    doc['cell']['positioners'] = doc['cell']['positioners'][:2]  # two balls: it would turn
    path_ = tmp_path / 'two_balls.yaml'
    path_.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match='cannot be watched'):
        force_watch(cell_file.load(path_), MECH)


def test_the_coordinator_stops_every_positioner_on_an_excess_naming_the_pair() -> None:
    watch = ForceWatch(CELL, MECH)
    fakes = [FakePositioner(n, after=None) for n in NAMES]
    settings = CoordinatorSettings(start_lead=0.05, poll_period=0.005, end_margin=5.0)
    coordinator = Coordinator(CELL, MECH, fakes, settings, watch=watch)
    points = np.array([a.point for a in CELL.attachments(MECH)])
    side = (points[2] - points[1]) / np.linalg.norm(points[2] - points[1])
    # the move's plans, from its start (the watch takes no plan begun before it)
    threading.Timer(0.2, lambda: fed(watch, {'p3': 3e-4 * side},
                                     t0=fakes[0].moved[-1][1].start)).start()
    outcome = coordinator.move(PanelRequest(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
                               threading.Event())
    assert outcome.code is ResultCode.ABORTED_INTERNAL_FORCE
    assert outcome.excess is not None and outcome.excess.pair == ('p2', 'p3')
    moved = np.zeros((3, 6))
    moved[2, :3] = 3e-4 * side
    solved = internal_forces(CELL.attachments(MECH), moved, CELL.panel.stiffness)
    assert outcome.excess.force == pytest.approx(solved.pairs[0][1], rel=1e-9)
    assert outcome.reason.startswith(f'internal force {solved.pairs[0][1]:.0f} N between p2 '
                                     'and p3 above the limit 500 N')
    assert all(f.stops == 1 for f in fakes)


def test_relax_moves_each_positioner_onto_the_rigid_placement_and_keeps_the_correction() -> None:
    """At rest, p2 measured 0.2 mm off along the side p1-p2: relax moves the three onto the
    rigid placement the readings imply (p1 and p2 0.1 mm toward each other's place, p3 by
    the mean's share), which loads the panel with nothing; the next panel move carries the
    corrections, and the watch takes them off the plans."""
    points = np.array([a.point for a in CELL.attachments(MECH)])
    side = (points[1] - points[0]) / np.linalg.norm(points[1] - points[0])
    watch = ForceWatch(CELL, MECH)
    fakes = [FakePositioner(n) for n in NAMES]
    coordinator = Coordinator(CELL, MECH, fakes, CoordinatorSettings(
        start_lead=0.05, poll_period=0.005, end_margin=5.0), watch=watch)
    refused = coordinator.relax(threading.Event())
    assert refused.code is ResultCode.REFUSED_TRACKER_SILENT
    assert 'p1, p2, p3' in refused.reason and not any(f.moved for f in fakes)
    off = {'p2': 2e-4 * side}
    for k in range(10):
        for name in NAMES:
            watch.reading(name, 50.0 + 0.05 * k, HOME_P + off.get(name, 0.0), HOME_Q)
    outcome = coordinator.relax(threading.Event())
    assert outcome.code is ResultCode.SUCCESS, outcome.reason
    assert outcome.reason.startswith('relaxed: moved p1 ')
    steps = {f.name: f.moved[0][0][0] - HOME_P for f in fakes}
    # After the steps the three attachment points are a rigid placement of the panel's.
    after = [(HOME_P + off.get(n, 0.0) + steps[n], HOME_Q) for n in NAMES]
    assert max(abs(d.stretch) for d in pair_disagreement(CELL, MECH, after)) < 1e-9
    np.testing.assert_allclose(steps['p2'] - steps['p1'], -2e-4 * side, atol=1e-12)
    for name in NAMES:
        np.testing.assert_allclose(coordinator.corrections[name], steps[name], atol=1e-15)
    # The next panel move: each goal carries its correction; positioners that now follow
    # their corrected plans load nothing.
    coordinator.move(PanelRequest(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
                     threading.Event())
    for fake in fakes:
        np.testing.assert_allclose(fake.moved[-1][0][0], HOME_P + steps[fake.name],
                                   atol=1e-12)
    start = fakes[0].moved[-1][1].start
    for name in NAMES:
        watch.plan(name, [start], [HOME_P + steps[name]], [HOME_Q])
        for k in range(3):
            watch.reading(name, start + 0.1 + 0.05 * k,
                          HOME_P + off.get(name, 0.0) + steps[name], HOME_Q)
    sizes = watch.sizes()
    assert sizes is not None and sizes[0][1] < 1e-3
