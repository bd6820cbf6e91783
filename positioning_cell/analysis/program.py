"""The run program of ``make run`` (``config/program.yaml``): named commanded poses (or a grid
of poses over a box: an accuracy map, config/accuracy_map.yaml), visited in order (or in a
``sequence`` of their names, repeats allowed: a pose approached from several directions,
config/acceptance.yaml) for a number of cycles, once per compensation mode; checked against
the mechanism's limits before anything moves. A ``compliance:`` block adds the static
compliance test at one of its poses (:mod:`positioning_cell.analysis.compliance_test`)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.analysis.compliance_test import ComplianceTest
from positioning_cell.config import load_parameter_file
from positioning_cell.core.limits import check_poses
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.pose_grid import PoseGrid, grid_poses
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.files import brief_errors, excerpt
from positioning_cell.parameters import parse

FloatArray = NDArray[np.float64]
MODES = ('none', 'model', 'measured')


@dataclass(frozen=True)
class Calibrating:
    """The ``program.calibration`` block: the run first calibrates the machine (calibrate_cell)
    with this many ``poses``, ``hold_out`` validation poses and tracker ``samples`` per pose."""

    poses: int
    hold_out: int
    samples: int


@dataclass(frozen=True)
class Program:
    """``names`` of the poses, their positions (K, 3) m and quaternions (K, 4) x, y, z, w in
    the base frame; ``cycles`` passes over them per mode in ``modes``, each pass visiting the
    poses in ``sequence`` (indices into ``names``, repeats allowed; empty: each pose once, in
    order); ``tolerance`` the settle tolerance of a move, m (0: the positioner's configured
    one); ``settle_timeout`` how long to wait for the monitor to see a move settle, s;
    ``calibration``, if given, the calibration run before the modes; ``compliance``, if
    given, the static compliance test after them."""

    names: tuple[str, ...]
    position: FloatArray
    quaternion: FloatArray
    cycles: int
    modes: tuple[str, ...]
    tolerance: float = 0.0
    settle_timeout: float = 5.0
    calibration: Calibrating | None = None
    sequence: tuple[int, ...] = ()
    compliance: ComplianceTest | None = None

    @property
    def order(self) -> tuple[int, ...]:
        """The pose indices one cycle visits, in order."""
        return self.sequence or tuple(range(len(self.names)))

    @property
    def moves(self) -> int:
        """Moves in the whole program."""
        return len(self.modes) * self.cycles * len(self.order)

    def steps(self) -> Iterator[tuple[str, int, int]]:
        """(mode, cycle from 1, pose index) of every move, in order."""
        for mode in self.modes:
            for cycle in range(1, self.cycles + 1):
                for k in self.order:
                    yield mode, cycle, k


def _number(block: Mapping[str, Any], key: str, default: float, low: float) -> float:
    value = block.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value >= low):
        raise ConfigError(f'program.{key} = {excerpt(value)}: must be a number >= {low}')
    return float(value)


def program_from(data: Mapping[str, Any], mech: Mechanism) -> Program:
    """The program in a parsed program file (``program:`` block, see config/program.yaml),
    every pose checked with :func:`positioning_cell.core.limits.check_poses`. ConfigError names
    what is wrong."""
    block = data.get('program')
    if not isinstance(block, Mapping):
        raise ConfigError('program file: no "program:" mapping')
    names, p, q = _poses(block, mech)
    cycles = block.get('cycles', 1)
    if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
        raise ConfigError(f'program.cycles = {excerpt(cycles)}: must be an integer >= 1')
    modes = block.get('modes', list(MODES))
    if (not isinstance(modes, list) or not modes
            or any(m not in MODES for m in modes) or len(set(modes)) != len(modes)):
        raise ConfigError(f'program.modes = {excerpt(modes)}: a list of distinct modes from '
                          f'{MODES}')
    return Program(tuple(names), p, q, cycles, tuple(modes),
                   _number(block, 'tolerance', 0.0, 0.0),
                   _number(block, 'settle_timeout', 5.0, 0.1), _calibrating(block),
                   _sequence(block, names), _compliance(block, names))


#: How the poses of a ``program.grid`` are named: G001, G002, … in grid order.
GRID_NAME = 'G{:03d}'


def _poses(block: Mapping[str, Any], mech: Mechanism
           ) -> tuple[list[str], FloatArray, FloatArray]:
    """The named poses of the ``program.poses`` mapping, or of a ``program.grid`` (a
    :class:`~positioning_cell.core.pose_grid.PoseGrid` over a box: an accuracy map, its
    poses outside the mechanism's limits left out, named :data:`GRID_NAME`), every pose
    checked with :func:`positioning_cell.core.limits.check_poses`."""
    poses, grid = block.get('poses'), block.get('grid')
    if grid is not None:
        if poses is not None:
            raise ConfigError('program: give poses or grid, not both')
        if not isinstance(grid, Mapping):
            raise ConfigError('program.grid: expected {centre, half_widths, points, tilt}')
        try:
            p, q = grid_poses(mech, parse(PoseGrid, dict(grid), 'program.grid.'),
                              'program.grid')
        except ValueError as err:  # ParameterError is one
            raise ConfigError(str(err)) from err
        names = [GRID_NAME.format(k + 1) for k in range(p.shape[0])]
    else:
        if not isinstance(poses, Mapping) or not poses:
            raise ConfigError('program.poses: expected a mapping of pose names to poses')
        names, positions, quaternions = [], [], []
        for name, pose in poses.items():
            if not isinstance(pose, Mapping) or 'position' not in pose:
                raise ConfigError(f'program.poses.{name}: expected {{position: [x, y, z], '
                                  f'orientation: [x, y, z, w]}}')
            names.append(str(name))
            positions.append(pose['position'])
            quaternions.append(pose.get('orientation', [0.0, 0.0, 0.0, 1.0]))
        try:
            p, q = as_pose_batch(positions, quaternions)
        except InputError as err:
            raise ConfigError(f'program.poses: {err}') from err
    report = check_poses(mech, p, q)
    if not report.ok:
        bad = report.first_bad_sample
        raise ConfigError(f'program.poses.{names[bad or 0]} is outside the workspace: '
                          f'{report.message()}')
    return names, p, q


def _sequence(block: Mapping[str, Any], names: list[str]) -> tuple[int, ...]:
    """The ``program.sequence`` block: pose names (repeats allowed) as indices into
    ``names``; () when not given."""
    sequence = block.get('sequence')
    if sequence is None:
        return ()
    if not isinstance(sequence, list) or not sequence:
        raise ConfigError(f'program.sequence = {excerpt(sequence)}: a non-empty list of pose '
                          f'names')
    unknown = [str(n) for n in sequence if str(n) not in names]
    if unknown:
        raise ConfigError(f'program.sequence names {", ".join(unknown)}, not in program.poses '
                          f'({", ".join(names)})')
    return tuple(names.index(str(n)) for n in sequence)


def _calibrating(block: Mapping[str, Any]) -> Calibrating | None:
    cal = block.get('calibration')
    if cal is None:
        return None
    if not isinstance(cal, Mapping):
        raise ConfigError('program.calibration: expected {poses: N, hold_out: H, samples: S}')
    values = []
    for key, low in (('poses', 8), ('hold_out', 0), ('samples', 1)):
        value = cal.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f'program.calibration.{key} = {excerpt(value)}: must be an integer '
                              f'>= {low}')
        values.append(value)
    unknown = set(cal) - {'poses', 'hold_out', 'samples'}
    if unknown:
        raise ConfigError(f'program.calibration.{sorted(unknown)[0]}: unknown key')
    return Calibrating(*values)


def _compliance(block: Mapping[str, Any], names: list[str]) -> ComplianceTest | None:
    """The ``program.compliance`` block (None: not given); its pose one of ``names``."""
    given = block.get('compliance')
    if given is None:
        return None
    if not isinstance(given, Mapping):
        raise ConfigError('program.compliance: expected a mapping (see config/acceptance.yaml)')
    try:
        test = parse(ComplianceTest, dict(given), 'program.compliance.')
    except ValueError as err:  # ParameterError is one
        raise ConfigError(str(err)) from err
    if test.pose not in names:
        raise ConfigError(f'program.compliance.pose = {test.pose}: not in program.poses '
                          f'({", ".join(names)})')
    return test


def load_program(path: str | Path, mech: Mechanism) -> Program:
    """Read and check a program file (:func:`program_from`)."""
    data = load_parameter_file(path)
    with brief_errors():
        return program_from(data, mech)


@dataclass(frozen=True)
class ProgramStep:
    """One step of the run program as published on /cell/program: compensation ``mode``,
    ``cycle`` (1-based) and ``pose`` name of the next move, ``stamp`` (s, publisher clock)
    and an optional ``note`` for the report; or, with ``end``, the end of a program (the
    moves after it, until the next step, belong to no program: :meth:`ended`)."""

    mode: str
    stamp: float
    cycle: int | None = None
    pose: str | None = None
    note: str | None = None
    end: bool = False

    @classmethod
    def ended(cls, stamp: float) -> ProgramStep:
        """The end-of-program marker at ``stamp`` (s, publisher clock)."""
        return cls('', stamp, end=True)

    def to_json(self) -> str:
        """The /cell/program message text."""
        doc: dict[str, Any] = {'mode': self.mode, 'cycle': self.cycle, 'pose': self.pose,
                               'stamp': self.stamp}
        if self.note:
            doc['note'] = self.note
        if self.end:
            doc['end'] = True
        return json.dumps(doc)

    @classmethod
    def from_json(cls, text: str, log_time: float) -> ProgramStep:
        """Parse a /cell/program message; ``log_time`` (s) stands in for a missing stamp.
        InputError for text that is not such a JSON object."""
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as err:
            raise InputError(f'/cell/program: not JSON ({err}): {text[:80]!r}') from err
        if not isinstance(doc, dict) or not isinstance(doc.get('mode'), str):
            raise InputError(f'/cell/program: expected an object with a "mode" string, '
                             f'got {text[:80]!r}')
        stamp = doc.get('stamp', log_time)
        cycle, pose, note = doc.get('cycle'), doc.get('pose'), doc.get('note')
        return cls(doc['mode'], float(stamp) if isinstance(stamp, (int, float)) else log_time,
                   cycle if isinstance(cycle, int) else None,
                   str(pose) if pose is not None else None,
                   str(note) if note is not None else None, doc.get('end') is True)
