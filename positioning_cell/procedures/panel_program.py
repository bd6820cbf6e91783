"""The coordinated cell's program (issue 27, ``run_cell --cell``): the panel moved through named
poses, cycle after cycle, each measured by the cell's tracker reading the panel's targets, for
the panel's ISO 9283 pose figures (:mod:`positioning_cell.analysis.panel`).

A program file (``config/panel_program.yaml``) holds four blocks:

- ``panel_program`` (:class:`PanelProgramSettings`): the cycles, the tracker readings averaged
  per pose, the panel's speed;
- ``poses``: each named pose as the panel's move from home, about the centroid of its
  attachment points (the ISO 9283 test point), in the cell frame: ``[x, y, z]`` m then the
  rotation vector ``[rx, ry, rz]`` rad (:func:`~positioning_cell.coordinated.panel_motion.
  panel_about`), visited in the file's order in every cycle;
- ``positioner_calibration`` (:class:`PositionerCalibrationSettings`): each positioner's own
  calibration, before the panel is mounted;
- ``panel_calibration`` (:class:`~positioning_cell.procedures.panel_calibration.
  PanelCalibrationSettings`): then the cell's, from the panel's targets.

:func:`run` drives the program on a :class:`~positioning_cell.procedures.panel_calibration.
PanelPort` and hands each step (:class:`PanelStep`: the commanded pose, when the move started
and settled, the readings' window and their mean) to ``record`` as it ends, so that a recorder
keeps what the offline analysis needs to take the same readings again from the bag. A move
that does not succeed is recorded with its code and the program goes on (the panel is where
the coordinator stopped it; the next move starts from there).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.config import load_parameter_file
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import panel_about
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.moves.correction import mean_pose
from positioning_cell.parameters import check_fields, parse_block, setting
from positioning_cell.procedures.panel_calibration import PanelCalibrationSettings, PanelPort

FloatArray = NDArray[np.float64]
Say = Callable[[str], None]

#: A pose's move (m) and turn (rad) from home, at most: well inside every positioner's stroke.
POSE_REACH = 0.05


@dataclass(frozen=True)
class PanelProgramSettings:
    """How the program visits its poses (module docstring)."""

    cycles: int = setting(3, 'times the poses are visited, in order (ISO 9283: 30; 3 '
                          'for a quick look)', low=1, high=1000)
    readings: int = setting(10, 'tracker readings averaged per pose', low=1, high=1000)
    speed_scale: float = setting(0.25, "the panel's moves, as a share of the positioners' "
                                 'speed limits', low=0.0, low_open=True, high=1.0)
    relax: bool = setting(True, "relax the panel from the legs' load cells (run_cell --cell: "
                          'once mounted, before the cell calibration, and again before the '
                          'poses; /cell_coordinator/relax_forces)')

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class PositionerCalibrationSettings:
    """Each positioner's own calibration before the panel is mounted (``run_cell --cell``:
    :func:`positioning_cell.procedures.calibration.calibrate` on each set, one after the other)."""

    enabled: bool = setting(True, "calibrate each positioner on its own first (off: the "
                            "positioners run on their nominal model)")
    poses: int = setting(20, 'D-optimal calibration poses', low=8, high=500)
    hold_out: int = setting(6, 'validation poses, never used in the fit', low=0, high=500)
    samples: int = setting(10, 'tracker readings averaged per pose', low=1, high=1000)
    at_once: bool = setting(True, 'every positioner calibrated at the same time (each its own '
                            'node set, tracker and client); off: one after the other')

    def __post_init__(self) -> None:
        check_fields(self)


class PanelProgram(NamedTuple):
    """A program file's blocks: the settings, the poses' names and their moves (K, 6) (m,
    rad: :func:`~positioning_cell.coordinated.panel_motion.panel_about`), the cell's
    calibration and each positioner's own."""

    settings: PanelProgramSettings
    names: tuple[str, ...]
    moves: FloatArray
    calibration: PanelCalibrationSettings
    positioners: PositionerCalibrationSettings

    @property
    def steps(self) -> int:
        """The program's moves."""
        return len(self.names) * self.settings.cycles


def _poses(raw: object, path: Path) -> tuple[tuple[str, ...], FloatArray]:
    if not isinstance(raw, Mapping) or not raw:
        raise ConfigError(f'{path}: poses: expected a mapping of pose names to '
                          '[x, y, z, rx, ry, rz] (m, rad)')
    rows = []
    for name, value in raw.items():
        where = f'{path}: poses.{name}'
        if (not isinstance(value, list) or len(value) != 6
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           for v in value)):
            raise ConfigError(f'{where}: expected [x, y, z, rx, ry, rz] (m, rad), got {value!r}')
        row = np.array(value, dtype=float)
        if not np.all(np.isfinite(row)) or np.max(np.abs(row)) > POSE_REACH:
            raise ConfigError(f'{where}: {value!r}: each value finite and within '
                              f'±{POSE_REACH} (m, rad) of home')
        rows.append(row)
    return tuple(str(k) for k in raw), np.array(rows)


def load_panel_program(path: str | Path) -> PanelProgram:
    """The program file at ``path`` (module docstring); ConfigError naming the file and the
    key of anything that cannot be used."""
    path = Path(path)
    names, moves = _poses(load_parameter_file(path).get('poses'), path)
    return PanelProgram(
        parse_block(PanelProgramSettings, path, 'panel_program'), names, moves,
        parse_block(PanelCalibrationSettings, path, 'panel_calibration'),
        parse_block(PositionerCalibrationSettings, path, 'positioner_calibration'))


def program_poses(cell: CellFile, mech: Mechanism, program: PanelProgram) -> list[Transform]:
    """The program's panel poses T_cell_panel, in its order, about the attachment points'
    centroid of ``cell``."""
    centre = cell.test_point(mech)
    return [panel_about(centre, row[:3], row[3:]) for row in program.moves]


@dataclass(frozen=True)
class PanelStep:
    """One move of the program: the cycle (from 1), the pose's name, the commanded panel pose
    (cell frame; m, x, y, z, w), the port's clock (s) when the move was sent and when it ended,
    how it ended (``code``: the coordinator's result code name, 'success' when it settled; its
    ``reason``), and, for a move that settled, the ``readings`` taken from ``settled`` on and
    their mean pose (m; x, y, z, w); none (0, NaN) otherwise. ``test_point``: the program's
    ISO 9283 test point (m, the panel frame's, i.e. the cell frame's with the panel at home),
    so that a recording of the steps is analysed without the cell file."""

    cycle: int
    pose: str
    test_point: tuple[float, ...]
    commanded_position: tuple[float, ...]
    commanded_quaternion: tuple[float, ...]
    started: float
    settled: float
    code: str
    reason: str
    readings: int
    measured_position: tuple[float, ...]
    measured_quaternion: tuple[float, ...]

    @property
    def succeeded(self) -> bool:
        """The move settled and was measured."""
        return self.code == 'success' and self.readings > 0

    def to_json(self) -> str:
        """The step as one JSON object (NaN as null), as /cell/panel_program carries it."""
        return json.dumps({k: ([None if math.isnan(x) else x for x in v]
                               if isinstance(v, tuple) else v)
                           for k, v in asdict(self).items()})

    @classmethod
    def from_json(cls, text: str) -> PanelStep:
        """Inverse of :meth:`to_json`; InputError for a record that is not a step."""
        try:
            raw = json.loads(text)
            values: dict[str, Any] = {k: (tuple(math.nan if x is None else float(x) for x in v)
                          if isinstance(v, list) else v) for k, v in raw.items()}
            return cls(**values)
        except (ValueError, TypeError, AttributeError) as err:
            raise InputError(f'not a panel program step: {text[:80]!r}: {err}') from err


def run(port: PanelPort, cell: CellFile, mech: Mechanism, program: PanelProgram,
        record: Callable[[PanelStep], None], say: Say = lambda line: None) -> list[PanelStep]:
    """The program (module docstring): every step, in order, each also handed to ``record``
    as it ends; a line per step."""
    poses = program_poses(cell, mech, program)
    centre = cell.test_point(mech)
    settings = program.settings
    steps = []
    none_p, none_q = (math.nan,) * 3, (math.nan,) * 4
    for cycle in range(1, settings.cycles + 1):
        for name, panel in zip(program.names, poses, strict=True):
            position, quaternion = panel.to_pq()
            started = port.now()
            moved = port.move_panel(position, quaternion, settings.speed_scale)
            settled = port.now()
            common = (cycle, name, _floats(centre), _floats(position), _floats(quaternion),
                      started, settled, moved.code or 'no_answer', moved.reason)
            if not moved.success:
                step = PanelStep(*common, 0, none_p, none_q)
                say(f'cycle {cycle} {name}: {step.code}: {moved.reason}')
            else:
                p, q = mean_pose(*port.panel_readings(settings.readings, settled))
                step = PanelStep(*common, settings.readings, _floats(p), _floats(q))
                off = np.linalg.norm(Transform.from_pq(p, q).apply(centre)
                                     - panel.apply(centre)) * 1e6
                say(f'cycle {cycle} {name}: measured {off:.1f} um from its goal at the '
                    'panel centre')
            record(step)
            steps.append(step)
    return steps


def _floats(values: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(values, dtype=float))
