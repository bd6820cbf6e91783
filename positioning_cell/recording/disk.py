"""Free space of the filesystem a bag is written to: measured (``statvfs``: what an unprivileged
writer may still use), the rate it falls at (whoever writes), and the recorder's two margins:
WARN below ``warn_free_bytes`` free, or when at the current rate the filesystem fills within
``warn_time_to_full_s``."""

from __future__ import annotations

import math
import os
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from positioning_cell.parameters import check_fields, setting

#: The falling rate of free space is measured over this window, s (at least half of it must
#: have been sampled).
RATE_WINDOW_S = 10.0
_UNITS = ('B', 'KiB', 'MiB', 'GiB', 'TiB', 'PiB')


@dataclass(frozen=True)
class DiskSettings:
    """When the recorder warns about the free space of its bag's filesystem."""

    warn_free_bytes: int = setting(2**30, 'WARN when the bag\'s filesystem has less free space '
                                   'than this', 'bytes', low=0, high=2**62)
    warn_time_to_full_s: float = setting(
        600.0, 'WARN when, at the rate free space fell over the last 10 s, the filesystem '
        'fills sooner than this (0: off)', 's', low=0.0, high=1e9)

    def __post_init__(self) -> None:
        check_fields(self)


def free_bytes(path: str | Path) -> int:
    """Bytes an unprivileged process may still write on the filesystem of ``path``
    (``f_bavail · f_frsize``); OSError if it cannot be asked."""
    stat = os.statvfs(path)
    return stat.f_bavail * stat.f_frsize


def human_bytes(n: float) -> str:
    """``n`` bytes for people, in binary units (``812 MiB``, ``1.5 GiB``)."""
    value, unit = float(n), 0
    while abs(value) >= 1024 and unit < len(_UNITS) - 1:
        value, unit = value / 1024, unit + 1
    return f'{value:.0f} {_UNITS[unit]}' if unit == 0 or abs(value) >= 100 else \
        f'{value:.1f} {_UNITS[unit]}'


def _duration(seconds: float) -> str:
    return f'{seconds:.0f} s' if seconds < 120 else f'{seconds / 60:.0f} min'


@dataclass(frozen=True)
class DiskReport:
    """The free space at one check: ``free_bytes`` (None: it could not be read, ``error``
    says why), ``falling_bytes_per_s`` (free space lost per second over the last
    :data:`RATE_WINDOW_S`; 0 when it did not fall; None until measured) and ``warning`` (''
    within the margins, else why not)."""

    free_bytes: int | None
    falling_bytes_per_s: float | None
    warning: str = ''
    error: str = ''

    @property
    def time_to_full_s(self) -> float:
        """When the filesystem fills at the falling rate, s (inf: not falling or unknown)."""
        rate = self.falling_bytes_per_s
        if self.free_bytes is None or not rate or rate <= 0:
            return math.inf
        return self.free_bytes / rate

    def values(self) -> dict[str, str]:
        """The diagnostic key-values: ``free_bytes``, ``disk_falling_bytes_per_s``,
        ``disk_full_in_s`` (empty while unknown, ``inf`` when not falling)."""
        rate = self.falling_bytes_per_s
        return {'free_bytes': '' if self.free_bytes is None else str(self.free_bytes),
                'disk_falling_bytes_per_s': '' if rate is None else f'{rate:.0f}',
                'disk_full_in_s': '' if rate is None else f'{self.time_to_full_s:.0f}'}


class FreeSpace:
    """Free-space samples (time s, bytes) in, :class:`DiskReport` out, judged against
    ``settings``."""

    def __init__(self, settings: DiskSettings) -> None:
        self.settings = settings
        self._samples: deque[tuple[float, int]] = deque()

    def update(self, now: float, free: int | None, error: str = '') -> DiskReport:
        """A check at time ``now`` (s, monotonic) that found ``free`` bytes (None: the check
        failed with ``error``)."""
        if free is None:
            return DiskReport(None, None, f'free space unknown: {error}', error)
        samples = self._samples
        samples.append((now, free))
        while samples and samples[0][0] < now - RATE_WINDOW_S:
            samples.popleft()
        (t0, f0) = samples[0]
        rate = max(0.0, (f0 - free) / (now - t0)) if now - t0 >= RATE_WINDOW_S / 2 else None
        report = DiskReport(free, rate)
        s = self.settings
        if free < s.warn_free_bytes:
            warning = (f'{human_bytes(free)} free, below the margin of '
                       f'{human_bytes(s.warn_free_bytes)}')
        elif s.warn_time_to_full_s and report.time_to_full_s < s.warn_time_to_full_s:
            warning = (f'disk full in about {_duration(report.time_to_full_s)} at '
                       f'{human_bytes(rate or 0)}/s (margin {_duration(s.warn_time_to_full_s)})')
        else:
            return report
        return DiskReport(free, rate, warning)
