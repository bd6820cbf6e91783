"""Named coordinate systems: any number of user and object systems stored by name, one of each
active (as a hexapod controller keeps its work, tool and levelling systems and switches between
them: PI C-887's KEN/KLD, Symétrie's user and object frames).

A user system is T_machine_user, an object system T_platform_object
(:mod:`positioning_cell.frames.systems`); the active pair is the
:class:`~positioning_cell.frames.systems.CoordinateSystems` every move, check and limit uses.
Each change gives a new value (frozen); an unknown or malformed name, or a kind that is neither
``user`` nor ``object``, is an InputError naming it and the known ones, and changes nothing.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

from positioning_cell.errors import InputError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform

#: The two kinds of system.
KINDS = ('user', 'object')
#: The name of the only system of each kind of a file that names none (the single-system form).
DEFAULT_NAME = 'default'
#: A name: a letter, then letters, digits, '_' or '-'; at most 32 characters.
NAME_PATTERN = re.compile(r'[A-Za-z][A-Za-z0-9_-]{0,31}')
#: At most this many systems of each kind (the file stays far below its 64 KiB bound).
MAX_SYSTEMS = 64


def check_name(name: str, kind: str = 'system') -> str:
    """``name`` if it is a valid system name, else InputError saying the rule."""
    if not isinstance(name, str) or NAME_PATTERN.fullmatch(name) is None:
        raise InputError(f'{kind} system name {name!r}: a letter, then letters, digits, _ or '
                         '-, at most 32 characters')
    return name


def check_kind(kind: str) -> str:
    """``kind`` if it is ``user`` or ``object``, else InputError."""
    if kind not in KINDS:
        raise InputError(f'coordinate system kind {kind!r}: expected one of {", ".join(KINDS)}')
    return kind


def _frozen(systems: Mapping[str, Transform]) -> Mapping[str, Transform]:
    return MappingProxyType(dict(systems))


@dataclass(frozen=True)
class NamedSystems:
    """The stored systems by kind and name, and the active name of each kind (module
    docstring). Built directly, every name must be valid, each kind hold at least one system
    and at most :data:`MAX_SYSTEMS`, and the active names exist (InputError otherwise)."""

    users: Mapping[str, Transform] = field(
        default_factory=lambda: _frozen({DEFAULT_NAME: Transform.identity()}))
    objects: Mapping[str, Transform] = field(
        default_factory=lambda: _frozen({DEFAULT_NAME: Transform.identity()}))
    active_user: str = DEFAULT_NAME
    active_object: str = DEFAULT_NAME

    def __post_init__(self) -> None:
        object.__setattr__(self, 'users', _frozen(self.users))
        object.__setattr__(self, 'objects', _frozen(self.objects))
        for kind in KINDS:
            stored = self.of(kind)
            if not stored or len(stored) > MAX_SYSTEMS:
                raise InputError(f'{kind} systems: {len(stored)} stored, expected 1 to '
                                 f'{MAX_SYSTEMS}')
            for name, value in stored.items():
                check_name(name, kind)
                if not isinstance(value, Transform):
                    raise InputError(f'{kind} system {name!r} must be a Transform')
            active = self.active_name(kind)
            if active not in stored:
                raise InputError(f'active {kind} system {active!r} is not one of '
                                 f'{", ".join(sorted(stored))}')

    @classmethod
    def single(cls, systems: CoordinateSystems) -> NamedSystems:
        """One system of each kind, named :data:`DEFAULT_NAME` (a file of the single form)."""
        return cls({DEFAULT_NAME: systems.user}, {DEFAULT_NAME: systems.object})

    def of(self, kind: str) -> Mapping[str, Transform]:
        """The stored systems of ``kind`` by name."""
        return self.users if check_kind(kind) == 'user' else self.objects

    def active_name(self, kind: str) -> str:
        """The active name of ``kind``."""
        return self.active_user if check_kind(kind) == 'user' else self.active_object

    @property
    def active(self) -> CoordinateSystems:
        """The active user and object systems."""
        return CoordinateSystems(self.users[self.active_user], self.objects[self.active_object])

    def defined(self, kind: str, name: str, value: Transform, *,
                activate: bool = False) -> NamedSystems:
        """With system ``name`` of ``kind`` set to ``value`` (new, or replacing one of that
        name), active if ``activate`` (or if it is the active one already)."""
        check_name(name, kind)
        stored = {**self.of(kind), name: value}
        if len(stored) > MAX_SYSTEMS:
            raise InputError(f'{kind} systems: at most {MAX_SYSTEMS} (remove one first)')
        key = 'users' if kind == 'user' else 'objects'
        changed = replace(self, **{key: stored})  # type: ignore[arg-type]
        return changed.selected(**{kind: name}) if activate else changed

    def selected(self, user: str | None = None, object: str | None = None) -> NamedSystems:
        """With the named systems active (None or '': that kind unchanged); InputError naming
        an unknown name and the stored ones."""
        chosen = {'user': user or self.active_user, 'object': object or self.active_object}
        for kind, name in chosen.items():
            if name not in self.of(kind):
                raise InputError(f'no {kind} system named {name!r}; stored: '
                                 f'{", ".join(sorted(self.of(kind)))}')
        return replace(self, active_user=chosen['user'], active_object=chosen['object'])

    def with_active(self, systems: CoordinateSystems) -> NamedSystems:
        """With the active systems' values set to ``systems`` (SetCoordinateSystems: the
        names stay, their values change)."""
        return replace(self, users={**self.users, self.active_user: systems.user},
                       objects={**self.objects, self.active_object: systems.object})
