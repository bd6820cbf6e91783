"""Which topics the recorder takes: the cell's topics (``positioning_cell.names.CELL_TOPICS``) by
default, or a list of names and/or a regular expression."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from positioning_cell.errors import InputError
from positioning_cell.names import CELL_TOPICS


@dataclass(frozen=True)
class TopicSelection:
    """Topics to record: those named in ``names`` plus those ``pattern`` fully matches."""

    names: frozenset[str]
    pattern: re.Pattern[str] | None = None

    @classmethod
    def from_params(cls, names: Sequence[str], pattern: str = '') -> TopicSelection:
        """From the recorder's ``topics`` list and ``topic_pattern`` regex; both empty means
        :data:`CELL_TOPICS`. Names must be absolute; InputError for a bad name or regex."""
        bad = [n for n in names if not n.startswith('/') or n.endswith('/') or ' ' in n]
        if bad:
            raise InputError(f'topics: {bad!r} are not absolute topic names ("/ns/name")')
        try:
            regex = re.compile(pattern) if pattern else None
        except re.error as err:
            raise InputError(f'topic_pattern = {pattern!r} is not a regular expression: {err}') \
                from err
        if not names and regex is None:
            return cls(frozenset(CELL_TOPICS))
        return cls(frozenset(names), regex)

    def matches(self, topic: str) -> bool:
        """True when ``topic`` is to be recorded."""
        return topic in self.names or (
            self.pattern is not None and self.pattern.fullmatch(topic) is not None)
