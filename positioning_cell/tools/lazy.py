"""A command-line tool's module kept light: its work lives in a sibling module, imported once
the command line is parsed, and its names stay reachable as the tool module's attributes."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def attributes_of(module: str, owner: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` (PEP 562) for module ``owner``: a name it does not define is
    looked up in ``module``, imported on first use (``from owner import name`` works too)."""

    def getattr_(name: str) -> Any:
        if not name.startswith('__'):  # not a lookup of Python's own (a spec, a registry)
            try:
                return getattr(importlib.import_module(module), name)
            except AttributeError:
                pass
        raise AttributeError(f'module {owner!r} has no attribute {name!r}')

    return getattr_
