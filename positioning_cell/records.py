"""Flat value records (frozen dataclasses of numbers, strings, tuples and None) as JSON-able
dicts, without ``dataclasses.asdict``'s deep copy (a report writes thousands of them)."""

from __future__ import annotations

from dataclasses import fields
from typing import Any


def plain_fields(record: Any) -> dict[str, Any]:
    """The fields of the dataclass instance ``record`` in declaration order, tuples as lists
    (values are not copied: the record is immutable)."""
    out: dict[str, Any] = {}
    for f in fields(record):
        value = getattr(record, f.name)
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out
