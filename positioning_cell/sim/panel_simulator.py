"""The ``panel_simulator`` node's work (simulation truth): its settings, and each cycle's panel
from the sets' true platform poses: the wrench on each platform and the internal forces
(:class:`~positioning_cell.sim.panel.PanelTruth` of the installed cell,
:mod:`~positioning_cell.sim.cell_installation`), the panel's true pose, and the cell tracker's
reading of the panel's targets (one fit per cycle, in the cell frame)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.settings import SHIPPED_CELL, cell_of
from positioning_cell.core.mechanism import Mechanism
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


class PanelSimulator:
    """The panel of the cell ``settings`` names, as installed (module docstring)."""

    def __init__(self, settings: PanelSimulatorSettings) -> None:
        self.settings = settings
        self.cell = settings.cell()  # ConfigError: no start
        self.installation = CellInstallation(self.cell, settings.mechanism,
                                             settings.installation)
        self._rng = np.random.default_rng(settings.seed)

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
