"""A command-line tool's module kept light: its work lives in a sibling module, imported once
the command line is parsed, and its names stay reachable as the tool module's attributes."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any


def attributes_of(load: Callable[[], ModuleType], owner: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` (PEP 562) for module ``owner``: a name it does not define is
    looked up in the module ``load()`` imports and returns, on first use (``from owner import
    name`` works too)."""

    def getattr_(name: str) -> Any:
        if not name.startswith('__'):  # not a lookup of Python's own (a spec, a registry)
            try:
                return getattr(load(), name)
            except AttributeError:
                pass
        raise AttributeError(f'module {owner!r} has no attribute {name!r}')

    return getattr_
