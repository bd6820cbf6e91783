"""Markdown tables for the reports and records (no other dependency: any report module may
use it)."""

from __future__ import annotations

from collections.abc import Sequence


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table (a ``|`` inside a cell is escaped)."""
    def row(cells: Sequence[str]) -> str:
        return '| ' + ' | '.join(c.replace('|', r'\|') for c in cells) + ' |'

    return [row(header), '|' + '---|' * len(header), *(row(r) for r in rows)]
