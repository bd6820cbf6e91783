"""The strain map (positioning_cell.coordinated.strain_map, issue 27 item 4): the affine map of
the panel's strain over its pose from the load cells' rests. Without ROS: samples made from a
known geometry (the cell file's bases turned and its sockets moved, what a cell holds and its
file does not), the map's change between two poses against that geometry's own, its span,
weights and the word it gives when the affine model falls short."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import bases, panel_about, platform_goals
from positioning_cell.coordinated.strain_map import (
    StrainMap,
    balls_in_base,
    fit_strain,
    pose_coordinates,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform

MECH = Mechanism.default()
CELL = cell_file.load(config_path('three_positioners.yaml'))
NONE = np.zeros((3, 3))


def machine(turn_mrad: float = 2.0, socket_um: float = 200.0) -> CellFile:
    """The cell as built: each base turned by up to ``turn_mrad`` and each socket moved by up
    to ``socket_um`` from the file (fixed, the same every run)."""
    rng = np.random.default_rng(7)
    sockets = CELL.panel_points(MECH) + rng.uniform(-1, 1, (3, 3)) * socket_um * 1e-6
    entries = []
    for e, socket in zip(CELL.positioners, sockets, strict=True):
        turned = Rotation.from_rotvec(rng.uniform(-1, 1, 3) * turn_mrad * 1e-3) \
            * Rotation.from_quat(e.base_quaternion)
        q = turned.as_quat()
        entries.append(replace(e, base_quaternion=(q[0], q[1], q[2], q[3]),
                               in_panel=(socket[0], socket[1], socket[2])))
    return replace(CELL, positioners=tuple(entries))


BUILT = machine()


def unstrained(panel: Transform, built: CellFile = BUILT) -> np.ndarray:
    """(3, 3) m: each ball in its base frame where the built cell holds it unstrained with the
    panel at ``panel``: its platform goals under the built geometry."""
    goals = platform_goals(built, MECH, *panel.to_pq())
    return balls_in_base(built, goals, NONE)


def commanded(panel: Transform) -> np.ndarray:
    """(3, 3) m: each ball in its base frame where the file's goals put it."""
    return balls_in_base(CELL, platform_goals(CELL, MECH, *panel.to_pq()), NONE)


def poses(n: int, reach: float = 6e-3, turn: float = 6e-3, seed: int = 1) -> list[Transform]:
    rng = np.random.default_rng(seed)
    centre = CELL.test_point(MECH)
    return [panel_about(centre, rng.uniform(-1, 1, 3) * reach, rng.uniform(-1, 1, 3) * turn)
            for _ in range(n)]


def learnt(samples: list[Transform], built: CellFile = BUILT) -> StrainMap:
    strain = StrainMap()
    for panel in samples:
        strain.add(unstrained(panel, built), NONE)
    return strain


def strain_left(panel: Transform, moved: np.ndarray, built: CellFile = BUILT) -> float:
    """m: the largest distance of a commanded ball (base frame, ``moved`` added to the file's
    goals) from the built cell's unstrained ball, once the rigid motion between the two sets
    is taken out (what strains the panel)."""
    base = bases(CELL)
    a = np.array([b.apply(p) for b, p in zip(base, commanded(panel) + moved, strict=True)])
    u = np.array([b.apply(p) for b, p in zip(base, unstrained(panel, built), strict=True)])
    a0, u0 = a - a.mean(axis=0), u - u.mean(axis=0)
    w, _, vt = np.linalg.svd(u0.T @ a0)
    rot = w @ vt
    if np.linalg.det(rot) < 0:
        w[:, -1] *= -1
        rot = w @ vt
    return float(np.linalg.norm(a0 @ rot.T - u0, axis=1).max())


def test_the_geometry_the_file_misses_strains_the_panel_more_away_from_home() -> None:
    """The premise: with one correction taken at home, the strain left grows with the pose."""
    home = Transform.identity()
    at_home = unstrained(home) - commanded(home)
    assert strain_left(home, at_home) < 1e-9
    far = [strain_left(p, at_home) for p in poses(20)]
    assert max(far) > 5e-6


@given(st.integers(0, 10_000))
def test_the_map_moves_the_home_correction_to_any_pose_within_a_micrometre(seed: int) -> None:
    """Learnt at 12 poses over ±6 mm / ±6 mrad, the map's change from home added to the
    correction found at home leaves < 1 µm of strain at other poses in that range, where the
    home correction alone leaves several."""
    strain = learnt(poses(12))
    fit = strain.fit(CELL, MECH)
    assert fit is not None and fit.samples == 12
    home = Transform.identity()
    at_home = unstrained(home) - commanded(home)
    (panel,) = poses(1, seed=seed)
    followed = at_home + fit.changes(panel, home)
    assert strain_left(panel, followed) < 1e-6
    assert fit.rms < 1e-6 and 'falls short' not in fit.words()


def test_the_map_waits_until_the_samples_span_the_pose() -> None:
    """Six poses, or any number at one pose, or poses that never turn: no map."""
    assert learnt(poses(6)).fit(CELL, MECH) is None
    assert learnt([Transform.identity()] * 20).fit(CELL, MECH) is None
    centre = CELL.test_point(MECH)
    rng = np.random.default_rng(3)
    shifted = [panel_about(centre, rng.uniform(-6e-3, 6e-3, 3), np.zeros(3))
               for _ in range(20)]
    assert learnt(shifted).fit(CELL, MECH) is None
    assert learnt(poses(7)).fit(CELL, MECH) is not None


def test_a_sample_counts_as_much_as_its_step_is_sure() -> None:
    """A sample whose step was large (a quarter of it uncertain) barely moves the map: one
    such sample 50 µm off changes the map's home value by well under a micrometre, while an
    equally far-off sample with a small step pulls it by micrometres."""
    good = poses(12)
    home = Transform.identity()

    def at_home(extra_step: float) -> np.ndarray:
        strain = learnt(good)
        off = unstrained(home) + np.array([[50e-6, 0, 0], [0, 0, 0], [0, 0, 0]])
        strain.add(off, np.full((3, 3), extra_step))
        fit = strain.fit(CELL, MECH)
        assert fit is not None
        return fit.constant

    reference = fit_strain(CELL, MECH, learnt(good)._samples)
    assert reference is not None
    unsure = np.abs(at_home(500e-6) - reference.constant).max()
    sure = np.abs(at_home(0.0) - reference.constant).max()
    assert unsure < 0.5e-6
    assert sure > 2e-6


def test_a_strain_no_affine_map_holds_is_said() -> None:
    """Samples off the affine model by 30 µm at random (a joint's play): the fit says its model
    falls short of them."""
    strain = StrainMap()
    rng = np.random.default_rng(5)
    for panel in poses(15):
        strain.add(unstrained(panel) + rng.normal(0.0, 30e-6, (3, 3)), NONE)
    fit = strain.fit(CELL, MECH)
    assert fit is not None and fit.factor > 3.0
    assert 'the affine model falls short of them' in fit.words()


def test_the_samples_are_the_machines_a_new_cell_file_reads_them_too() -> None:
    """The same samples under a calibrated file (the built bases): the map then needs no
    change between poses (the file holds the geometry)."""
    strain = learnt(poses(12))
    under_built = strain.fit(BUILT, MECH)
    assert under_built is not None
    (panel,) = poses(1, seed=99)
    assert np.abs(under_built.changes(panel, Transform.identity())).max() < 1e-9
    assert np.abs(pose_coordinates(Transform.identity())).max() == 0.0


def test_bad_samples_are_refused_and_change_nothing() -> None:
    strain = learnt(poses(8))
    before = len(strain)
    for balls, steps in ((np.full((3, 3), np.nan), NONE), (np.zeros((3, 2)), NONE),
                         (np.zeros((3, 3)), np.zeros((2, 3)))):
        with pytest.raises(InputError, match='strain sample'):
            strain.add(balls, steps)
    assert len(strain) == before
    with pytest.raises(InputError, match='platforms and steps'):
        balls_in_base(CELL, [], NONE)
    with pytest.raises(InputError, match='floor'):
        StrainMap(floor=0.0)
