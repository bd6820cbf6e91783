"""How long an input stream (the encoders' joint states, the tracker's readings) has been silent,
judged from what the positioner's looks at it found, not from the clock alone.

The positioner takes its inputs when it looks (``Mover._refresh``); a look finds the messages
that came in since the one before, or none. The silence a stream has *shown* runs from the
last look that found a message to the last look that found none. Time in which nobody looked
(this process held up by a loaded machine: descheduled, or a thread waiting on a lock) is not
silence the stream showed: the clock's "now minus the last message" counted it, and a
positioner held up for 0.47 s aborted a homing for a driver that published every 10 ms
throughout (test_cli_on_the_cell, issue 24). It counts once a look after it finds nothing
either. A stream that really stops is still found silent as soon as before, within one look
period: the mover looks every ``POLL_PERIOD`` while it waits. Times in s on one monotonic
clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Hearing:
    """What the looks at one stream found: ``heard_at``, the latest look that found a message
    (-inf: none yet); ``missed_at``, the latest look that found none."""

    heard_at: float = -math.inf
    missed_at: float = -math.inf

    def look(self, t: float, found: bool) -> None:
        """A look at ``t`` s found a message (``found``) or none. Looks of several threads may
        be recorded out of order: each time keeps its latest."""
        if found:
            self.heard_at = max(self.heard_at, t)
        else:
            self.missed_at = max(self.missed_at, t)

    def silence(self) -> float:
        """The silence the looks showed, s: from the latest look that found a message to a
        later one that found none (0 when the latest look found one; inf when none ever
        did)."""
        if math.isinf(self.heard_at):
            return math.inf
        return max(0.0, self.missed_at - self.heard_at)
