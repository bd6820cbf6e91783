"""A send rate limit that tolerates jitter: a token bucket. Inputs that come at the limit
itself (a 20 Hz tracker under a 20 Hz limit) all pass although their intervals scatter about
the period; faster inputs are thinned to the limit on average."""

from __future__ import annotations

import math

from positioning_cell.errors import InputError


class Throttle:
    """At most ``rate`` (Hz) passes per second on average, bursts of up to ``burst`` passes
    (≥ 1; 2 lets an interval as short as 0 through after a long one)."""

    def __init__(self, rate: float, burst: float = 2.0) -> None:
        if not (math.isfinite(rate) and rate > 0.0):
            raise InputError(f'rate = {rate!r}: must be a finite number > 0')
        if not (math.isfinite(burst) and burst >= 1.0):
            raise InputError(f'burst = {burst!r}: must be a finite number >= 1')
        self.rate, self.burst = float(rate), float(burst)
        self._tokens = self.burst
        self._last: float | None = None

    def allow(self, now: float) -> bool:
        """Whether an event at time ``now`` (s, monotonic) may pass; a pass spends a token."""
        if self._last is not None:
            self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False
