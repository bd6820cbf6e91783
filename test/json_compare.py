"""Comparing two JSON documents of figures: where they differ, numbers within rounding."""

from __future__ import annotations

import math


def differences(old: object, new: object, path: str = '') -> list[str]:
    """Where two JSON documents differ: numbers beyond 1e-12 relative and 1e-14 absolute (the
    last bits of a sum or of a mean rotation), anything else at all."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = [f'{path}: keys {sorted(set(old) ^ set(new))}'] if set(old) != set(new) else []
        return out + [d for k in old if k in new
                      for d in differences(old[k], new[k], f'{path}.{k}')]
    if isinstance(old, list) and isinstance(new, list):
        if len(old) != len(new):
            return [f'{path}: {len(old)} != {len(new)} items']
        return [d for i, (a, b) in enumerate(zip(old, new, strict=True))
                for d in differences(a, b, f'{path}[{i}]')]
    if isinstance(old, float) and isinstance(new, float):
        same = (old == new or (math.isnan(old) and math.isnan(new))
                or abs(old - new) <= 1e-12 * max(abs(old), abs(new)) + 1e-14)
        return [] if same else [f'{path}: {old!r} != {new!r}']
    return [] if old == new else [f'{path}: {old!r} != {new!r}']
