"""The coordinated cell's settings: the coordinator's time base (:class:`CoordinatorSettings`)
and every parameter of the ``cell_coordinator`` node (:class:`CellCoordinatorSettings`)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.cell_file import load as load_cell
from positioning_cell.coordinated.strain_map import StrainMap
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError
from positioning_cell.parameters import check_fields, group, parse, setting

#: The shipped coordinated cell (config/).
SHIPPED_CELL = 'three_positioners.yaml'


def cell_of(cell_file: str) -> CellFile:
    """The cell file a node's ``cell_file`` parameter names (empty: the shipped one);
    ConfigError naming what is wrong in it."""
    return load_cell(Path(cell_file) if cell_file else config_path(SHIPPED_CELL))


@dataclass(frozen=True)
class CoordinatorSettings:
    """The coordinator's timing (``cell_coordinator`` parameters)."""

    start_lead: float = setting(0.5, 'the common start lies this far ahead of the moment the '
                                'moves are sent (each positioner plans and sends within it; '
                                'at most the drives\' command.max_start_delay)', 's',
                                low=0.05, high=5.0)
    poll_period: float = setting(0.01, 'how often the running moves are looked at', 's',
                                 low=0.001, high=0.5)
    end_margin: float = setting(60.0, 'a move not over this long after the common motion '
                                'ends (settling, corrections) stops every positioner', 's',
                                low=1.0, high=3600.0)
    stop_lead: float = setting(0.15, 'a stop of a panel move starts this far ahead of the '
                               'moment it is sent, one instant for every positioner (each '
                               'hears it within it; a positioner that hears it later stops at '
                               'once)', 's', low=0.02, high=2.0)
    stop_time: float = setting(0.3, 'a stopped panel move comes to rest along its path within '
                               'this long, or within its own ramp when shorter (a quarter of '
                               'its duration)', 's', low=0.01, high=10.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class RelaxSettings:
    """How the coordinator relaxes the panel from its load cells
    (:meth:`~positioning_cell.coordinated.coordinator.Coordinator.relax_forces`;
    ``cell_coordinator`` parameters)."""

    passes: int = setting(3, 'at most this many relaxing moves per command: a real panel is '
                          "not as stiff as its file, and each move leaves that error's share",
                          low=1, high=10)
    enough: float = setting(50.0, 'the relax ends once the largest internal force the load '
                            'cells give is at most this', 'N', low=0.0, high=1.0e5)
    window: float = setting(0.5, "each set's load cells and encoders are averaged over this "
                            'long at rest', 's', low=0.05, high=10.0)
    follow_pose: bool = setting(True, 'the load corrections follow the panel: the load cells '
                                'read at every rest (each relaxing move, and after each '
                                'settled panel move) feed an affine map of the strain over the '
                                'pose, used once it spans the six coordinates '
                                '(positioning_cell.coordinated.strain_map; false: one '
                                'correction for every pose)')

    def __post_init__(self) -> None:
        check_fields(self)

    def strain_map(self) -> StrainMap | None:
        """An empty strain map when the load corrections follow the pose, else None."""
        return StrainMap() if self.follow_pose else None


def replacing(current: CellFile, new: CellFile) -> CellFile:
    """``new``, to stand for ``current`` in a running coordinator (a calibrated file of the same
    cell): the same positioners in the same order, as its subscriptions and its ports are
    bound to their namespaces; ConfigError naming the difference."""
    was, now = [e.name for e in current.positioners], [e.name for e in new.positioners]
    if was != now:
        raise ConfigError(f'cell_file: positioners {now} are not the running cell\'s {was}: '
                          'restart the coordinator for another cell')
    return new


@dataclass(frozen=True)
class CellCoordinatorSettings:
    """Every parameter of the ``cell_coordinator`` node (read-only but ``cell_file``: restart
    to change them)."""

    mechanism: Mechanism = group(Mechanism, "the positioners' nominal machine: each one's "
                                 "home pose is the panel's home")
    cell_file: str = setting('', 'the coordinated cell: its positioners (their namespaces), '
                             'bases and attachments (docs/howto/coordinated.md); empty: the '
                             f'shipped config/{SHIPPED_CELL}. Set while the node runs, a file '
                             'of the same positioners (a calibration: calibrate_panel), taken '
                             'from the next panel move on; refused during one', dynamic=True)
    timing: CoordinatorSettings = group(CoordinatorSettings, "the panel moves' time base")
    answer_timeout: float = setting(10.0, "longest wait for a positioner's answer to a check "
                                    'or a stop', 's', low=0.1, high=120.0)
    relax: RelaxSettings = group(RelaxSettings, 'the relax from the load cells '
                                 '(/cell_coordinator/relax_forces)')

    def __post_init__(self) -> None:
        check_fields(self)

    def cell(self) -> CellFile:
        """The cell file (ConfigError naming what is wrong in it)."""
        return cell_of(self.cell_file)

    @classmethod
    def from_file(cls, path: str | Path) -> CellCoordinatorSettings:
        """From the ``cell_coordinator`` section (and ``/**``) of a ROS 2 parameter file, as
        the node receives them: the keys it does not declare (the blocks shared with other
        nodes: payload, structure) are left out."""
        params = node_parameters(load_parameter_file(path), names.NODE_COORDINATOR)
        own = {f.name for f in fields(cls)}
        return parse(cls, {k: v for k, v in params.items() if k in own})
