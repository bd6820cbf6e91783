"""ISO 230-2:2014, accuracy and repeatability of positioning of one numerically controlled
axis, from its standard test: m target positions P_i, each approached n times in the positive
direction (↑) and n times in the negative direction (↓), the actual position P_ij measured by a
reference instrument at each stop. Pure numpy; any unit, as long as the targets and the
measured positions share it (the cell: m for leg lengths, rad for the θ axes).

The figures (ISO 230-2:2014 clause 3, terms and definitions; i = 1..m targets, j = 1..n
cycles; the clause numbers are those of the 2006 and 2014 editions as we know them, not checked
against the text itself, which is not public):

- §3.5 positional deviation x_ij = P_ij − P_i (actual minus target);
- §3.10 mean unidirectional positional deviation at a position x̄_i↑ = (1/n) Σ_j x_ij↑, x̄_i↓;
- §3.11 mean bidirectional positional deviation at a position x̄_i = (x̄_i↑ + x̄_i↓) / 2;
- §3.12 reversal value at a position B_i = x̄_i↑ − x̄_i↓; §3.13 of the axis B = max |B_i|;
  §3.14 mean reversal value of the axis B̄ = (1/m) Σ B_i;
- §3.15 estimator of the unidirectional standard uncertainty of positioning at a position
  s_i↑ = √(Σ_j (x_ij↑ − x̄_i↑)² / (n − 1)), s_i↓;
- §3.16 unidirectional repeatability at a position R_i↑ = 4 s_i↑, R_i↓ = 4 s_i↓;
- §3.17 bidirectional repeatability at a position R_i = max(2 s_i↑ + 2 s_i↓ + |B_i|; R_i↑; R_i↓);
- §3.18 unidirectional repeatability of the axis R↑ = max R_i↑, R↓ = max R_i↓;
  §3.19 bidirectional R = max R_i;
- §3.20 unidirectional systematic positional deviation of the axis E↑ = max x̄_i↑ − min x̄_i↑,
  E↓ likewise; §3.21 bidirectional E = max(x̄_i↑; x̄_i↓) − min(x̄_i↑; x̄_i↓): the range over
  both directions' means (not E↑, not max(E↑, E↓));
- §3.22 mean bidirectional positional deviation of the axis M = max x̄_i − min x̄_i;
- §3.23 unidirectional accuracy of the axis A↑ = max(x̄_i↑ + 2 s_i↑) − min(x̄_i↑ − 2 s_i↑),
  A↓ likewise; §3.24 bidirectional A = max(x̄_i↑ + 2 s_i↑; x̄_i↓ + 2 s_i↓)
  − min(x̄_i↑ − 2 s_i↑; x̄_i↓ − 2 s_i↓).

Editions: ISO 230-2:1988 stated accuracy and repeatability with 3 standard deviations (as
VDI/DGQ 3441 did); its revision replaced them by 2 standard uncertainties (R_i↑ = 4 s_i↑,
A with ±2 s; the 1997 edition as we understand it, AMT's note describing the change without
naming the edition), kept since: the 2006 edition has the measurement uncertainty per
ISO/TR 230-9 (Annex A) and the optional step cycle (Annex B); 2014 adds periodic errors
(Annex C) and ball array and step gauge tests (Annex D). Implemented: the 2014 edition,
coverage factor 2; the 1988 figures are not offered. Laser calibration software keeps the
editions apart (the remote interface of Agilent's E1733A lists "ISO 230-2 1988", "1997",
"2006" and "2014" as different analysis standards).

Sources (the standard's text is not public): the scopes of ISO 230-2:2006 and :2014 as the
standards bodies publish them (globalspec, evs.ee/en/iso-230-2-2014); AMT (amtonline.org,
with the 2006 edition: "instead of using 3 'standard deviations' (old standard),
2 'standard uncertainties' are used ... The calculation for 'standard uncertainty' is the
same as for 'standard deviation'"); and a published worked report with its complete data,
the ESS ecmc motion test report of 3 Nov 2021 (ecmc_bifrost_slits_sat, tests_2/11358/axis1,
5 targets x 5 cycles, written by ESS's ecmcISO230_2.py), whose x̄, s, R_i, B_i, B, B̄, E↑,
E↓, M, A↑, A↓ and A this module reproduces (test/test_iso230_2.py). That report's axis R is
max(R↑, R↓) (the standard: max R_i, larger there: 8.35 against 7.50 µm) and its E is E↓ (a
min taken as a max; the standard's E is 15.99 µm against 14.85 µm printed); in its other
reports the same code prints E = E↑.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The standard and edition implemented.
STANDARD = 'ISO 230-2:2014'

#: Display units of :meth:`AxisFigures.markdown`: name → (factor from SI, symbol, kind,
#: decimals). Lengths from m, angles from rad.
UNITS: dict[str, tuple[float, str, str, int]] = {
    'm': (1.0, 'm', 'length', 7),
    'mm': (1e3, 'mm', 'length', 4),
    'um': (1e6, 'µm', 'length', 2),
    'µm': (1e6, 'µm', 'length', 2),
    'rad': (1.0, 'rad', 'angle', 7),
    'mrad': (1e3, 'mrad', 'angle', 4),
    'urad': (1e6, 'µrad', 'angle', 1),
    'µrad': (1e6, 'µrad', 'angle', 1),
    'deg': (180.0 / math.pi, 'deg', 'angle', 5),
}

#: The axis figures, in the order of the tables: (attribute, symbol).
AXIS_FIGURES = (('A', 'A'), ('A_up', 'A↑'), ('A_down', 'A↓'), ('R', 'R'), ('R_up', 'R↑'),
                ('R_down', 'R↓'), ('B', 'B'), ('B_mean', 'B̄'), ('E', 'E'), ('E_up', 'E↑'),
                ('E_down', 'E↓'), ('M', 'M'))
#: The per-target figures, in the order of the tables: (attribute, symbol).
TARGET_FIGURES = (('x_mean_up', 'x̄↑'), ('x_mean_down', 'x̄↓'), ('x_mean', 'x̄'),
                  ('s_up', 's↑'), ('s_down', 's↓'), ('R_i_up', 'R_i↑'),
                  ('R_i_down', 'R_i↓'), ('R_i', 'R_i'), ('B_i', 'B_i'))


@dataclass(frozen=True, eq=False)
class AxisFigures:
    """ISO 230-2:2014 figures of one axis (module docstring), in the unit of its input.

    Per target (m,): ``targets`` P_i; ``x_mean_up`` x̄_i↑, ``x_mean_down`` x̄_i↓, ``x_mean``
    x̄_i; ``s_up`` s_i↑, ``s_down`` s_i↓; ``R_i_up`` R_i↑, ``R_i_down`` R_i↓, ``R_i``; ``B_i``.
    The deviations x_ij (n, m): ``x_up``, ``x_down`` (row j = cycle j + 1). Of the axis:
    ``A``, ``A_up``, ``A_down``, ``R``, ``R_up``, ``R_down``, ``B``, ``B_mean`` (B̄), ``E``,
    ``E_up``, ``E_down``, ``M``. Arrays are read-only."""

    targets: FloatArray
    x_up: FloatArray
    x_down: FloatArray
    x_mean_up: FloatArray
    x_mean_down: FloatArray
    x_mean: FloatArray
    s_up: FloatArray
    s_down: FloatArray
    R_i_up: FloatArray
    R_i_down: FloatArray
    R_i: FloatArray
    B_i: FloatArray
    A: float
    A_up: float
    A_down: float
    R: float
    R_up: float
    R_down: float
    B: float
    B_mean: float
    E: float
    E_up: float
    E_down: float
    M: float

    @property
    def cycles(self) -> int:
        """n, the approaches of each target in each direction."""
        return int(self.x_up.shape[0])

    @property
    def positions(self) -> int:
        """m, the target positions."""
        return int(self.targets.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: ``standard``, ``n``, ``m``, every array as a list and every figure as a
        float, in the unit of the input."""
        doc: dict[str, Any] = {'standard': STANDARD, 'n': self.cycles, 'm': self.positions,
                               'targets': self.targets.tolist(), 'x_up': self.x_up.tolist(),
                               'x_down': self.x_down.tolist()}
        doc.update({name: getattr(self, name).tolist() for name, _ in TARGET_FIGURES})
        doc.update({name: float(getattr(self, name)) for name, _ in AXIS_FIGURES})
        return doc

    def markdown(self, unit: str = 'um', *, target_unit: str | None = None) -> list[str]:
        """The figures as two Markdown tables for people (lines, no trailing newline): one row
        per target (P_i in ``target_unit``; x̄↑, x̄↓, x̄, s↑, s↓, R_i↑, R_i↓, R_i, B_i in
        ``unit``), then one row of the axis figures A, A↑, A↓, R, R↑, R↓, B, B̄, E, E↑, E↓, M.
        The input is taken to be SI: m for a length ``unit`` (mm, um / µm), rad for an angle
        one (mrad, urad / µrad, deg). ``target_unit`` defaults to mm for lengths and to mrad
        (deg with ``unit='deg'``) for angles. InputError for an unknown unit or a target unit
        of the other kind."""
        factor, symbol, kind, decimals = _unit(unit, 'unit')
        if target_unit is None:
            target_unit = 'mm' if kind == 'length' else ('deg' if unit == 'deg' else 'mrad')
        t_factor, t_symbol, t_kind, t_decimals = _unit(target_unit, 'target_unit')
        if t_kind != kind:
            raise InputError(f'target_unit = {target_unit!r} is an {t_kind} unit but unit = '
                             f'{unit!r} is a {kind} unit')

        def value(x: float, signed: bool = False) -> str:
            shown = round(x * factor, decimals) + 0.0  # no '-0.00'
            return f'{shown:{"+" if signed else ""}.{decimals}f}'

        signed = {'x_mean_up', 'x_mean_down', 'x_mean', 'B_i'}
        head = ['i', f'P_i ({t_symbol})'] + [f'{s} ({symbol})' for _, s in TARGET_FIGURES]
        lines = ['| ' + ' | '.join(head) + ' |', '|' + '---:|' * len(head)]
        for i in range(self.positions):
            cells = [str(i + 1), f'{self.targets[i] * t_factor:+.{t_decimals}f}']
            cells += [value(float(getattr(self, name)[i]), name in signed)
                      for name, _ in TARGET_FIGURES]
            lines.append('| ' + ' | '.join(cells) + ' |')
        lines.append('')
        lines.append('| ' + ' | '.join(f'{s} ({symbol})' for _, s in AXIS_FIGURES) + ' |')
        lines.append('|' + '---:|' * len(AXIS_FIGURES))
        lines.append('| ' + ' | '.join(value(float(getattr(self, name)), name == 'B_mean')
                                       for name, _ in AXIS_FIGURES) + ' |')
        return lines


def _unit(name: str, what: str) -> tuple[float, str, str, int]:
    try:
        return UNITS[name]
    except (KeyError, TypeError):
        raise InputError(f'{what} = {name!r}: one of {", ".join(UNITS)}') from None


def _numbers(value: ArrayLike, name: str) -> FloatArray:
    try:
        return np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected numbers, got {value!r}') from err


def _finite(arr: FloatArray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        where = np.argwhere(bad)[0]
        if arr.ndim == 1:
            raise InputError(f'{name}[{where[0]}] = {float(arr[where[0]])!r} is not finite '
                             '(NaN or infinite)')
        j, i = (int(k) for k in where)
        raise InputError(f'{name}[{j}, {i}] (cycle {j + 1}, target {i + 1}) = '
                         f'{float(arr[j, i])!r} is not finite (NaN or infinite)')


def validated(targets: ArrayLike, forward: ArrayLike,
              backward: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The inputs of :func:`iso230_2` as float arrays: targets (m,) finite and distinct, m >= 2;
    forward and backward (n, m) finite, n >= 2. InputError naming what is wrong."""
    p = _numbers(targets, 'targets')
    if p.ndim != 1:
        raise InputError(f'targets: expected shape (m,), got {p.shape}')
    if p.shape[0] < 2:
        raise InputError(f'targets: at least 2 target positions (m >= 2), got {p.shape[0]}')
    _finite(p, 'targets')
    order = np.argsort(p, kind='stable')
    same = np.flatnonzero(np.diff(p[order]) == 0.0)
    if same.size:
        a, b = sorted((int(order[same[0]]), int(order[same[0] + 1])))
        raise InputError(f'targets[{a}] = targets[{b}] = {float(p[a])!r}: each target position '
                         'once')
    m = p.shape[0]
    out = []
    for name, value in (('forward', forward), ('backward', backward)):
        arr = _numbers(value, name)
        if arr.ndim != 2 or arr.shape[1] != m:
            raise InputError(f'{name}: expected shape (n, {m}) (cycles, targets), got '
                             f'{arr.shape}')
        if arr.shape[0] < 2:
            raise InputError(f'{name}: at least 2 cycles (n >= 2) to estimate s, got '
                             f'{arr.shape[0]}')
        _finite(arr, name)
        out.append(arr)
    if out[0].shape != out[1].shape:
        raise InputError(f'forward has {out[0].shape[0]} cycles but backward has '
                         f'{out[1].shape[0]}: each target is approached n times in each '
                         'direction')
    return p, out[0], out[1]


def _readonly(a: FloatArray) -> FloatArray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def iso230_2(targets: ArrayLike, forward: ArrayLike, backward: ArrayLike) -> AxisFigures:
    """ISO 230-2:2014 figures of one axis (module docstring) from its target positions P_i
    (m,) and the actual positions P_ij measured at them, ``forward`` (n, m) approached in the
    positive direction (↑) and ``backward`` (n, m) in the negative one (↓), row j the cycle
    j + 1, column i the target i; all in one unit (the figures are in it too). InputError for
    shapes that do not match, NaN or infinite values, fewer than 2 targets or cycles, or a
    target given twice."""
    p, up, down = validated(targets, forward, backward)
    x_up, x_down = up - p, down - p                                  # §3.5
    figures: dict[str, Any] = {name: _readonly(v)
                               for name, v in target_figures(x_up, x_down).items()}
    figures.update(zip((name for name, _ in AXIS_FIGURES), axis_figures(x_up, x_down).tolist(),
                       strict=True))
    return AxisFigures(targets=_readonly(p), x_up=_readonly(x_up), x_down=_readonly(x_down),
                       **figures)


def target_figures(x_up: ArrayLike, x_down: ArrayLike) -> dict[str, FloatArray]:
    """The per-target figures (..., m) by their names in :data:`TARGET_FIGURES` (x̄↑, x̄↓, x̄,
    s↑, s↓, R_i↑, R_i↓, R_i, B_i; module docstring) of the positional deviations x_ij↑, x_ij↓
    (..., n, m), batched over the leading axes."""
    up, down = np.asarray(x_up, dtype=float), np.asarray(x_down, dtype=float)
    mean_up, mean_down = up.mean(axis=-2), down.mean(axis=-2)        # §3.10
    b_i = mean_up - mean_down                                        # §3.12
    s_up, s_down = up.std(axis=-2, ddof=1), down.std(axis=-2, ddof=1)  # §3.15
    r_up, r_down = 4.0 * s_up, 4.0 * s_down                          # §3.16
    return {'x_mean_up': mean_up, 'x_mean_down': mean_down,
            'x_mean': (mean_up + mean_down) / 2.0,                   # §3.11
            's_up': s_up, 's_down': s_down, 'R_i_up': r_up, 'R_i_down': r_down,
            'R_i': np.maximum(2.0 * s_up + 2.0 * s_down + np.abs(b_i),
                              np.maximum(r_up, r_down)),             # §3.17
            'B_i': b_i}


def axis_figures(x_up: ArrayLike, x_down: ArrayLike) -> FloatArray:
    """The axis figures (..., 12) in :data:`AXIS_FIGURES` order (A, A↑, A↓, R, R↑, R↓, B, B̄,
    E, E↑, E↓, M; module docstring) of the positional deviations x_ij↑, x_ij↓ (..., n, m),
    batched over the leading axes (from :func:`target_figures`)."""
    t = target_figures(x_up, x_down)
    mean_up, mean_down, s_up, s_down = t['x_mean_up'], t['x_mean_down'], t['s_up'], t['s_down']
    b_i, mean = t['B_i'], t['x_mean']
    high_up, low_up = (mean_up + 2.0 * s_up).max(-1), (mean_up - 2.0 * s_up).min(-1)
    high_down, low_down = (mean_down + 2.0 * s_down).max(-1), (mean_down - 2.0 * s_down).min(-1)
    means_high = np.maximum(mean_up.max(-1), mean_down.max(-1))
    means_low = np.minimum(mean_up.min(-1), mean_down.min(-1))
    out: FloatArray = np.stack([
        np.maximum(high_up, high_down) - np.minimum(low_up, low_down),  # §3.24
        high_up - low_up, high_down - low_down,                      # §3.23
        t['R_i'].max(-1), t['R_i_up'].max(-1), t['R_i_down'].max(-1),  # §3.19, 3.18
        np.abs(b_i).max(-1), b_i.mean(-1),                           # §3.13, 3.14
        means_high - means_low,                                      # §3.21
        mean_up.max(-1) - mean_up.min(-1), mean_down.max(-1) - mean_down.min(-1),  # §3.20
        mean.max(-1) - mean.min(-1)], axis=-1)                       # §3.22
    return out
