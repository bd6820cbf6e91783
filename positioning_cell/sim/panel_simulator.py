"""The ``panel_simulator`` node's work (simulation truth): its settings, and each cycle's panel
from the sets' true platform poses: the wrench on each platform and the internal forces
(:class:`~positioning_cell.sim.panel.PanelTruth` of the installed cell,
:mod:`~positioning_cell.sim.cell_installation`), each pair's stretch, the panel's true pose,
and the cell tracker's reading of the panel's targets (one fit per cycle, in the cell frame).

The sets' true poses come each on its own stream (50 Hz, stamped with the instant they
describe, on the clock all the sets share). A cycle takes them at one instant: the latest
that every stream has reached, each pose interpolated there. The latest pose of each instead
would be up to a period apart: 100 µm at 10 mm/s, read as a stretch of the panel that is not
there whenever the platforms move."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import PairDisagreement, pair_disagreement
from positioning_cell.coordinated.settings import SHIPPED_CELL, cell_of
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import interpolated_pose
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.sim.cell_installation import CellInstallation, InstallationSettings
from positioning_cell.sim.panel import PanelState

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PanelSimulatorSettings:
    """Every parameter of the ``panel_simulator`` node (read-only)."""

    mechanism: Mechanism = group(Mechanism, "the positioners' nominal machine: each one's "
                                 "home pose is the panel's home")
    cell_file: str = setting('', 'the coordinated cell (its panel: mass, centre of gravity, '
                             f'stiffness); empty: the shipped config/{SHIPPED_CELL}')
    rate_hz: float = setting(20.0, 'how often the wrenches, the internal forces and the '
                             "panel's poses (true, measured) are published", 'Hz', low=1.0,
                             high=200.0)
    installation: InstallationSettings = group(
        InstallationSettings, 'the cell as installed: its bases and sockets off the cell '
        "file, the cell tracker's true pose and systematic errors")
    seed: int = setting(0, "seed of the cell tracker's reading noise", low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_fields(self)

    def cell(self) -> CellFile:
        """The cell file (ConfigError naming what is wrong in it)."""
        return cell_of(self.cell_file)


class PanelReading(NamedTuple):
    """One fit of the cell tracker's readings of the panel's targets: ``position`` (3,) m,
    ``quaternion`` (4,), ``covariance`` (6, 6) (δp m, δθ rad about the cell axes), cell
    frame."""

    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray


class PanelCycle(NamedTuple):
    """One cycle (module docstring): the instant ``stamp`` s it describes, the panel's
    ``state`` there, the tracker's ``reading`` of it and each pair's ``stretches`` (truth:
    :func:`~positioning_cell.coordinated.panel_motion.pair_disagreement` on the installed
    cell)."""

    stamp: float
    state: PanelState
    reading: PanelReading
    stretches: tuple[PairDisagreement, ...]

    def forces_record(self) -> dict[str, Any]:
        """The record of /sim/panel/internal_forces: the instant, the largest force at one
        attachment and each pair's force N (largest first), the largest stretch and each
        pair's µm."""
        return {'stamp': self.stamp, 'largest_n': round(self.state.largest, 3),
                'pairs': [{'pair': list(pair), 'force_n': round(force, 3)}
                          for pair, force in self.state.pairs],
                'largest_stretch_um': round(max((abs(d.stretch) for d in self.stretches),
                                                default=0.0) * 1e6, 3),
                'stretches': [{'pair': [d.first, d.second],
                               'stretch_um': round(d.stretch * 1e6, 3)}
                              for d in self.stretches]}


#: The true poses kept of each set (a second of them at 50 Hz).
POSES_KEPT = 50


class PanelSimulator:
    """The panel of the cell ``settings`` names, as installed (module docstring)."""

    def __init__(self, settings: PanelSimulatorSettings) -> None:
        self.settings = settings
        self.cell = settings.cell()  # ConfigError: no start
        self.installation = CellInstallation(self.cell, settings.mechanism,
                                             settings.installation)
        self._rng = np.random.default_rng(settings.seed)
        self._poses: dict[str, deque[tuple[float, FloatArray, FloatArray]]] = {
            name: deque(maxlen=POSES_KEPT) for name in self.names}

    def true_pose(self, name: str, stamp: float, position: ArrayLike,
                  quaternion: ArrayLike) -> None:
        """Set ``name``'s true platform pose (in its base) at ``stamp`` s; an older stamp than
        its last starts its stream again (a restarted set)."""
        series = self._poses[name]
        if series and stamp <= series[-1][0]:
            series.clear()
        series.append((float(stamp), np.asarray(position, dtype=float),
                       np.asarray(quaternion, dtype=float)))

    def cycle(self) -> PanelCycle | None:
        """The panel at the latest instant every set's stream has reached (module docstring);
        None until every set has sent a pose."""
        if not all(self._poses.values()):
            return None
        stamp = min(series[-1][0] for series in self._poses.values())
        platforms = [interpolated_pose([t for t, _, _ in series], [p for _, p, _ in series],
                                       [q for _, _, q in series], stamp)
                     for series in (self._poses[name] for name in self.names)]
        state, reading = self.step(platforms)
        stretches = pair_disagreement(self.installation.true_cell, self.settings.mechanism,
                                      platforms)
        return PanelCycle(stamp, state, reading, tuple(stretches))

    @cached_property
    def names(self) -> tuple[str, ...]:
        """The positioners' names, in the cell file's order."""
        return tuple(e.name for e in self.cell.positioners)

    def step(self, platforms: Sequence[tuple[ArrayLike, ArrayLike]]
             ) -> tuple[PanelState, PanelReading]:
        """The panel on the true platform poses (each (position (3,) m, quaternion (4,)) in
        its base, in the cell's order), and the tracker's reading of it."""
        state = self.installation.panel.state(platforms)
        p, q, cov = self.installation.read_panel([state.panel], self._rng)
        return state, PanelReading(p[0], q[0], cov[0])
