"""The coordinated cell's configuration (issue 27): the positioners holding one panel, each
with its base in the cell frame and its attachment to the panel (config/three_positioners.yaml
is the shipped one; docs/howto/coordinated.md).

Format (YAML; lengths m, quaternions x, y, z, w)::

    cell:
      positioners:
        - name: p1                        # its namespace, later its node set's
          base: [x, y, z, qx, qy, qz, qw] # its base frame in the cell frame
          attachment:
            kind: spherical               # clamp, spherical, ball_in_slot, ball_on_plane
            offset: [0.0, 0.0, 0.05]      # the ball (clamp reference) in the platform frame
            direction: [1.0, 0.0, 0.0]    # slot axis / flat normal, cell frame (else unused)
            in_panel: [0.0, 0.0, 0.246]   # optional: the ball in the panel frame (a cell
                                          # calibration's; default: where the platform puts
                                          # it at home)
      panel:                              # optional; these are the defaults
        mass: 0.0                         # kg
        centre_of_gravity: [0.0, 0.0, 0.0]  # m, cell frame, the panel at home
        stiffness: [1.0e+7, 1.0e+4]       # N/m, N·m/rad: each attachment's force and couple
                                          # lines (positioner and panel in series)
        internal_force_limit: 500.0       # N: a panel move whose internal force exceeds it
                                          # stops every positioner

Every positioner has the machine of :class:`~positioning_cell.core.mechanism.Mechanism` given
to :meth:`CellFile.attachments` (the default: seed 000's); an attachment's point in the cell
frame is where its platform puts it at home, unless the file gives it (``in_panel``: the
socket's place in the panel, which a cell calibration identifies with the base,
:mod:`.cell_calibration`). The panel frame coincides with the cell frame when the panel is at
home. Every refusal is a ConfigError naming the file, the positioner and the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import files
from positioning_cell.config import load_yaml_mapping
from positioning_cell.coordinated.attachments import Attachment
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import matrix_from_quaternion
from positioning_cell.errors import ConfigError, InputError

FloatArray = NDArray[np.float64]

#: Fewest and most positioners of a coordinated cell.
MIN_POSITIONERS, MAX_POSITIONERS = 1, 4
_POSITIONER_KEYS = {'name', 'base', 'attachment'}
_PANEL_KEYS = {'mass', 'centre_of_gravity', 'stiffness', 'internal_force_limit'}
#: Gravity in the cell frame, m/s² (z up).
GRAVITY = (0.0, 0.0, -9.80665)


@dataclass(frozen=True)
class Panel:
    """The panel: ``mass`` kg at ``centre_of_gravity`` (3,) m (cell frame, the panel at home),
    each attachment's ``stiffness`` (k_force N/m, k_couple N·m/rad: the positioner and the
    panel in series), and the ``internal_force_limit`` N above which a panel move stops."""

    mass: float = 0.0
    centre_of_gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stiffness: tuple[float, float] = (1.0e7, 1.0e4)
    internal_force_limit: float = 500.0

    def weight(self) -> FloatArray:
        """The panel's weight as a wrench (6,) on it: force N, moment N·m about the cell
        origin."""
        force = self.mass * np.asarray(GRAVITY)
        return np.concatenate([force, np.cross(np.asarray(self.centre_of_gravity), force)])
_ATTACHMENT_KEYS = {'kind', 'offset', 'direction', 'in_panel'}


@dataclass(frozen=True)
class PositionerEntry:
    """One positioner of the cell: ``base`` its base frame in the cell frame (position (3,) m,
    unit quaternion (4,)), and its attachment's kind, ``offset`` (3,) m in the platform frame,
    ``direction`` (3,) in the cell frame and ``in_panel`` (3,) m, its point in the panel frame
    (None: where the platform puts it at home)."""

    name: str
    base_position: tuple[float, float, float]
    base_quaternion: tuple[float, float, float, float]
    kind: str
    offset: tuple[float, float, float]
    direction: tuple[float, float, float]
    in_panel: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class CellFile:
    """A coordinated cell's configuration (module docstring)."""

    path: Path
    positioners: tuple[PositionerEntry, ...]
    panel: Panel = Panel()

    def test_point(self, mech: Mechanism | None = None) -> FloatArray:
        """(3,) m: the panel's ISO 9283 test point, its attachment points' centroid in the
        panel frame (:meth:`panel_points`)."""
        out: FloatArray = self.panel_points(mech).mean(axis=0)
        return out

    def panel_points(self, mech: Mechanism | None = None) -> FloatArray:
        """(N, 3) m: each attachment's point in the panel frame (the cell frame, the panel at
        home): its ``in_panel``, else where its platform puts it at home (``mech``: the
        positioners' machine, default seed 000's)."""
        machine = mech or Mechanism.default()
        out = np.empty((len(self.positioners), 3))
        for k, entry in enumerate(self.positioners):
            if entry.in_panel is not None:
                out[k] = entry.in_panel
                continue
            rotation = matrix_from_quaternion(np.asarray(entry.base_quaternion)[None])[0]
            out[k] = np.asarray(entry.base_position) + rotation @ (
                machine.home_position + np.asarray(entry.offset))
        return out

    def attachments(self, mech: Mechanism | None = None) -> list[Attachment]:
        """Each positioner's attachment with its point in the cell frame, the panel at home
        (:meth:`panel_points`)."""
        return [Attachment(entry.name, entry.kind, (float(x), float(y), float(z)),
                           entry.direction)
                for entry, (x, y, z) in zip(self.positioners, self.panel_points(mech),
                                            strict=True)]

    def as_yaml(self) -> dict[str, Any]:
        """The file's content (what :func:`load` reads back to an equal CellFile)."""
        positioners = []
        for e in self.positioners:
            attachment: dict[str, Any] = {'kind': e.kind, 'offset': list(e.offset),
                                          'direction': list(e.direction)}
            if e.in_panel is not None:
                attachment['in_panel'] = list(e.in_panel)
            positioners.append({'name': e.name,
                                'base': [*e.base_position, *e.base_quaternion],
                                'attachment': attachment})
        p = self.panel
        return {'cell': {'positioners': positioners, 'panel': {
            'mass': p.mass, 'centre_of_gravity': list(p.centre_of_gravity),
            'stiffness': list(p.stiffness), 'internal_force_limit': p.internal_force_limit}}}


def _numbers(value: object, n: int, where: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ConfigError(f'{where}: expected a list of {n} numbers, got {value!r}')
    out = tuple(float(v) for v in value)
    if not np.isfinite(out).all():
        raise ConfigError(f'{where}: {list(out)} is not finite')
    return out


def _entry(raw: object, k: int, source: str) -> PositionerEntry:
    where = f'{source}: cell.positioners[{k}]'
    if not isinstance(raw, Mapping):
        raise ConfigError(f'{where}: expected a mapping, got {raw!r}')
    unknown = sorted(set(raw) - _POSITIONER_KEYS)
    if unknown or not {'name', 'base', 'attachment'} <= set(raw):
        raise ConfigError(f'{where}: keys must be {sorted(_POSITIONER_KEYS)} (unknown: '
                          f'{unknown}, missing: {sorted(_POSITIONER_KEYS - set(raw))})')
    name = raw['name']
    if not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(f'{where}.name: {name!r} is not a name (letters, digits, _)')
    where = f'{source}: positioner {name}'
    base = _numbers(raw['base'], 7, f'{where}.base')
    norm = float(np.linalg.norm(base[3:]))
    if abs(norm - 1.0) > 1e-6:
        raise ConfigError(f'{where}.base: the quaternion {list(base[3:])} is not unit '
                          f'(norm {norm:.9g})')
    att = raw['attachment']
    if not isinstance(att, Mapping) or set(att) - _ATTACHMENT_KEYS or 'kind' not in att:
        raise ConfigError(f'{where}.attachment: expected a mapping with kind (and offset, '
                          f'direction), got {att!r}')
    offset = _numbers(att.get('offset', [0.0, 0.0, 0.0]), 3, f'{where}.attachment.offset')
    direction = _numbers(att.get('direction', [0.0, 0.0, 1.0]), 3,
                         f'{where}.attachment.direction')
    in_panel = (None if att.get('in_panel') is None else
                _numbers(att['in_panel'], 3, f'{where}.attachment.in_panel'))
    entry = PositionerEntry(
        name, (base[0], base[1], base[2]), (base[3], base[4], base[5], base[6]),
        str(att['kind']), (offset[0], offset[1], offset[2]),
        (direction[0], direction[1], direction[2]),
        None if in_panel is None else (in_panel[0], in_panel[1], in_panel[2]))
    try:  # the attachment's own rules (kind, direction)
        Attachment(name, entry.kind, entry.offset, entry.direction)
    except InputError as err:
        raise ConfigError(f'{where}.attachment: {err}') from err
    return entry


def _panel(raw: object, source: str) -> Panel:
    where = f'{source}: cell.panel'
    if not isinstance(raw, Mapping) or set(raw) - _PANEL_KEYS:
        raise ConfigError(f'{where}: expected a mapping of {sorted(_PANEL_KEYS)}, got {raw!r}')
    default = Panel()
    mass = _numbers([raw.get('mass', default.mass)], 1, f'{where}.mass')[0]
    cog = _numbers(raw.get('centre_of_gravity', list(default.centre_of_gravity)), 3,
                   f'{where}.centre_of_gravity')
    stiffness = _numbers(raw.get('stiffness', list(default.stiffness)), 2, f'{where}.stiffness')
    limit = _numbers([raw.get('internal_force_limit', default.internal_force_limit)], 1,
                     f'{where}.internal_force_limit')[0]
    if mass < 0.0 or min(stiffness) <= 0.0 or limit <= 0.0:
        raise ConfigError(f'{where}: mass must be >= 0, stiffness and internal_force_limit '
                          f'> 0 (got mass {mass}, stiffness {list(stiffness)}, limit {limit})')
    return Panel(mass, (cog[0], cog[1], cog[2]), (stiffness[0], stiffness[1]), limit)


def load(path: str | Path) -> CellFile:
    """The cell file ``path`` (ConfigError naming the file and what is wrong)."""
    data: dict[str, Any] = load_yaml_mapping(path, files.CELL_FILE, 'cell')
    source = files.describe(files.CELL_FILE, path)
    cell = data.get('cell')
    if (set(data) != {'cell'} or not isinstance(cell, Mapping)
            or not {'positioners'} <= set(cell) <= {'positioners', 'panel'}):
        raise ConfigError(f'{source}: expected one key `cell` holding `positioners` (and '
                          '`panel`)')
    raw = cell['positioners']
    if not isinstance(raw, list) or not MIN_POSITIONERS <= len(raw) <= MAX_POSITIONERS:
        raise ConfigError(f'{source}: cell.positioners must list {MIN_POSITIONERS} to '
                          f'{MAX_POSITIONERS} positioners')
    entries = tuple(_entry(item, k, source) for k, item in enumerate(raw))
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise ConfigError(f'{source}: positioner names repeat: {names}')
    return CellFile(Path(path), entries, _panel(cell.get('panel', {}), source))
