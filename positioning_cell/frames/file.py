"""The coordinate systems file: the user and object CS as they survive a restart.

One YAML mapping under ``coordinate_systems:`` with the keys ``user`` (T_machine_user) and
``object`` (T_platform_object) of the active systems and, for the named systems
(:mod:`positioning_cell.frames.named`), ``active`` (``{user: NAME, object: NAME}``) and
``named`` (``{user: {NAME: system, ...}, object: {...}}``); a file without the last two (the
single form) holds one system of each kind, named ``default``. The active named systems must
be the ``user`` and ``object`` entries. Each system has ``position_m`` (3 numbers, m),
``quaternion_xyzw`` (4 numbers, unit within 1e-6) and, optionally, ``human``
(``'Tx Ty Tz mm Rx Ry Rz deg'``, R = Rz·Ry·Rx, six decimals). The SI fields are the truth;
``human`` is for people and, when present, must agree with them (to its printed precision), so
that a hand edit of it alone is refused rather than silently ignored::

    coordinate_systems:
      user:
        position_m: [0.01, 0.0, 0.0]
        quaternion_xyzw: [0.0, 0.0, 0.0, 1.0]
        human: 10.000000 0.000000 0.000000 mm 0.000000 0.000000 0.000000 deg
      object: ...

:func:`write` replaces the file atomically (temporary file in the same directory, flushed to
disk, then renamed): a reader sees the old file or the new one, never half of one.
:func:`write` creates the file's folder when missing. :func:`load` of a missing file gives the
identity systems (nothing was ever defined); any other problem (unreadable, not a regular file,
larger than 64 KiB, not YAML or YAML the bounded loader refuses (:mod:`positioning_cell.files`),
a missing or unknown key, not numbers, NaN or infinite, a non-unit quaternion, a ``human``
field that disagrees) raises
:class:`CoordinateSystemsFileError` naming the file and the problem, and changes nothing.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from positioning_cell import files
from positioning_cell.core.poses import as_unit_quaternions
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.frames.named import KINDS, NamedSystems
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform, distance, format_human

#: The top-level key, and the systems under it in file order; then the named systems' keys.
ROOT_KEY = 'coordinate_systems'
SYSTEM_KEYS = KINDS
NAMED_KEYS = ('active', 'named')
#: How closely the active named systems must equal the ``user`` and ``object`` entries.
SAME_POSITION, SAME_ANGLE = 1e-12, 1e-12
#: The keys of one system: required, then optional.
REQUIRED_KEYS = ('position_m', 'quaternion_xyzw')
OPTIONAL_KEYS = ('human',)
#: How closely ``human`` must agree with the SI fields: its six decimals of mm and deg.
HUMAN_POSITION_TOLERANCE = 1e-9  # m
HUMAN_ANGLE_TOLERANCE = 5e-8  # rad (three angles rounded to 5e-7 deg each)

_HEADER = ('# Coordinate systems of the positioner (positioning_cell.frames.file).\n'
           '# user = T_machine_user (in the machine CS), object = T_platform_object (in the\n'
           '# platform frame; its origin is the pivot). position_m and quaternion_xyzw (SI) are\n'
           "# the values; 'human' (mm, deg, R = Rz*Ry*Rx) must agree with them.\n")

__all__ = ['CoordinateSystemsFileError', 'document', 'dump', 'load', 'load_named', 'parse',
           'parse_named', 'write']


class CoordinateSystemsFileError(ConfigError):
    """A coordinate systems file that cannot be used: unreadable, malformed or inconsistent
    (the message names the file and the problem)."""


# -- writing -------------------------------------------------------------------------------------
def _entry(t: Transform) -> dict[str, Any]:
    p, q = t.to_pq()
    return {'position_m': [float(v) for v in p], 'quaternion_xyzw': [float(v) for v in q],
            'human': format_human(t.to_human())}


def document(systems: CoordinateSystems | NamedSystems) -> dict[str, Any]:
    """The file's content (module docstring) for ``systems`` (a single pair: named
    ``default``)."""
    named = systems if isinstance(systems, NamedSystems) else NamedSystems.single(systems)
    active = named.active
    return {ROOT_KEY: {
        'user': _entry(active.user), 'object': _entry(active.object),
        'active': {kind: named.active_name(kind) for kind in KINDS},
        'named': {kind: {name: _entry(t) for name, t in named.of(kind).items()}
                  for kind in KINDS}}}


def dump(systems: CoordinateSystems | NamedSystems) -> str:
    """The file's text for ``systems``: a comment header, then :func:`document` in YAML."""
    return _HEADER + yaml.safe_dump(document(systems), sort_keys=False,
                                    default_flow_style=None, width=99)


def write(path: str | Path, systems: CoordinateSystems | NamedSystems) -> Path:
    """Write ``systems`` to ``path`` atomically (module docstring), its folder created when
    missing (``$ROS_HOME/positioning_cell`` on a fresh ROS_HOME); the path written.
    CoordinateSystemsFileError if it cannot be written (the old file then stays as it was)."""
    out = Path(path)
    text = dump(systems)
    tmp: str | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f'.{out.name}.', suffix='.tmp', dir=out.parent)
        with os.fdopen(fd, 'w', encoding='utf-8') as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, out)
        tmp = None
        _sync_directory(out.parent)
    except OSError as err:
        raise CoordinateSystemsFileError(
            f'coordinate systems file {str(out)!r}: cannot be written ({err.strerror or err})'
        ) from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    return out


def _sync_directory(directory: Path) -> None:
    """Flush a rename in ``directory`` to disk (POSIX; a no-op where it cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# -- reading -------------------------------------------------------------------------------------
def load(path: str | Path) -> CoordinateSystems:
    """The active coordinate systems of the file ``path`` (:func:`load_named`)."""
    return load_named(path).active


def load_named(path: str | Path) -> NamedSystems:
    """The named coordinate systems of the file ``path``; the identity systems, named
    ``default``, if it does not exist. CoordinateSystemsFileError naming the file and the
    problem otherwise (read by :func:`positioning_cell.files.load_yaml`: a regular file of at
    most :data:`~positioning_cell.files.COORDINATE_SYSTEMS_FILE`'s size; a short message)."""
    data = files.load_yaml(path, files.COORDINATE_SYSTEMS_FILE, CoordinateSystemsFileError,
                           missing_ok=True)
    if data is files.MISSING:
        return NamedSystems()
    with files.brief_errors():
        return parse_named(data, files.describe(files.COORDINATE_SYSTEMS_FILE, path))


def parse(data: Any, where: str = 'coordinate systems') -> CoordinateSystems:
    """The active coordinate systems of a loaded document (:func:`parse_named`)."""
    return parse_named(data, where).active


def parse_named(data: Any, where: str = 'coordinate systems') -> NamedSystems:
    """The named coordinate systems of a loaded document (:func:`document`'s form, or the
    single form); CoordinateSystemsFileError prefixed with ``where`` if it is not one."""
    if not isinstance(data, dict) or set(data) != {ROOT_KEY}:
        found = (files.excerpt(sorted(map(str, data))) if isinstance(data, dict)
                 else type(data).__name__)
        raise CoordinateSystemsFileError(
            f'{where}: expected exactly one mapping "{ROOT_KEY}:", found {found}')
    body = data[ROOT_KEY]
    if not isinstance(body, dict):
        raise CoordinateSystemsFileError(f'{where}: "{ROOT_KEY}" is not a mapping')
    _check_keys(body, SYSTEM_KEYS, NAMED_KEYS, ROOT_KEY, where)
    user, obj = (_system(body[name], name, where) for name in SYSTEM_KEYS)
    given = [k for k in NAMED_KEYS if k in body]
    if not given:
        return NamedSystems.single(CoordinateSystems(user=user, object=obj))
    if len(given) != len(NAMED_KEYS):
        raise CoordinateSystemsFileError(f'{where}: {ROOT_KEY} has {given[0]} without '
                                         f'{(set(NAMED_KEYS) - set(given)).pop()}')
    active, named = body['active'], body['named']
    for key, value in (('active', active), ('named', named)):
        if not isinstance(value, dict):
            raise CoordinateSystemsFileError(f'{where}: {key} is not a mapping')
        _check_keys(value, KINDS, (), key, where)
    stored = {}
    for kind in KINDS:
        if not isinstance(named[kind], dict):
            raise CoordinateSystemsFileError(f'{where}: named.{kind} is not a mapping')
        stored[kind] = {str(name): _system(entry, f'named.{kind}.{name}', where)
                        for name, entry in named[kind].items()}
    try:
        systems = NamedSystems(stored['user'], stored['object'], str(active['user']),
                               str(active['object']))
    except InputError as err:
        raise CoordinateSystemsFileError(f'{where}: {err}') from None
    for kind, value in zip(KINDS, (user, obj), strict=True):
        dp, angle = distance(value, systems.of(kind)[systems.active_name(kind)])
        if dp > SAME_POSITION or angle > SAME_ANGLE:
            raise CoordinateSystemsFileError(
                f'{where}: {kind} is not the active named system '
                f'{systems.active_name(kind)!r} (off by {dp * 1e3:.6f} mm, '
                f'{math.degrees(angle):.6f} deg): the two must agree')
    return systems


def _check_keys(entry: dict[Any, Any], required: tuple[str, ...], optional: tuple[str, ...],
                name: str, where: str) -> None:
    missing = [k for k in required if k not in entry]
    unknown = sorted(str(k) for k in entry if k not in required + optional)
    if missing or unknown:
        said = ([f'lacks {", ".join(missing)}'] if missing else []) + (
            [f'has unknown keys {", ".join(unknown)}'] if unknown else [])
        allowed = ', '.join(required + optional)
        raise CoordinateSystemsFileError(f'{where}: {name} {" and ".join(said)} '
                                         f'(expected {allowed})')


def _numbers(value: Any, count: int, name: str, where: str) -> list[float]:
    if not isinstance(value, list) or len(value) != count or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        hint = ''
        if isinstance(value, list) and any(isinstance(v, str) and _is_float(v) for v in value):
            hint = ' (YAML reads 1e-3 as text: write 1.0e-3)'
        raise CoordinateSystemsFileError(f'{where}: {name} = {files.excerpt(value)}: expected '
                                         f'a list of {count} numbers{hint}')
    if not all(math.isfinite(v) for v in value):
        raise CoordinateSystemsFileError(f'{where}: {name} = {files.excerpt(value)}: not '
                                         'finite (NaN or infinite)')
    return [float(v) for v in value]


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _system(entry: Any, name: str, where: str) -> Transform:
    if not isinstance(entry, dict):
        raise CoordinateSystemsFileError(f'{where}: {name} is not a mapping')
    _check_keys(entry, REQUIRED_KEYS, OPTIONAL_KEYS, name, where)
    p = _numbers(entry['position_m'], 3, f'{name}.position_m', where)
    q = _numbers(entry['quaternion_xyzw'], 4, f'{name}.quaternion_xyzw', where)
    try:
        transform = Transform.from_pq(p, as_unit_quaternions(q, f'{name}.quaternion_xyzw')[0])
    except InputError as err:
        raise CoordinateSystemsFileError(f'{where}: {err}') from None
    if 'human' in entry:
        _check_human(entry['human'], transform, f'{name}.human', where)
    return transform


def _check_human(value: Any, transform: Transform, name: str, where: str) -> None:
    """``value`` is the six-decimal human text of ``transform``, to its printed precision."""
    tokens = value.split() if isinstance(value, str) else []
    numbers: list[float] = []
    if len(tokens) == 8 and tokens[3] == 'mm' and tokens[7] == 'deg':
        with contextlib.suppress(ValueError):
            numbers = [float(t) for i, t in enumerate(tokens) if i not in (3, 7)]
    if len(numbers) != 6 or not np.isfinite(numbers).all():
        raise CoordinateSystemsFileError(f'{where}: {name} = {files.excerpt(value, 100)}: '
                                         "expected 'Tx Ty Tz mm Rx Ry Rz deg' (six finite "
                                         'numbers)')
    dp, angle = distance(transform, Transform.from_human(numbers))
    if dp > HUMAN_POSITION_TOLERANCE or angle > HUMAN_ANGLE_TOLERANCE:
        said = format_human(transform.to_human())
        raise CoordinateSystemsFileError(
            f'{where}: {name} = {files.excerpt(value, 100)} disagrees with position_m and '
            f'quaternion_xyzw ({said!r}; off by {dp * 1e3:.3g} mm, {math.degrees(angle):.3g} '
            'deg): edit the '
            "SI fields, and correct or delete 'human'")
