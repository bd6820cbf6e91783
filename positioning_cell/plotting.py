"""Figures for the reports (PNG through matplotlib's Agg renderer, no pyplot: no global state,
safe in worker processes and threads), one place for how a figure is made and saved."""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Resolution of every report figure (a 12-inch figure is 1320 pixels wide).
DPI = 110


def figure(width: float, height: float, rows: int = 1, columns: int = 1, *,
           margins: tuple[float, float, float, float] = (0.07, 0.98, 0.93, 0.1),
           space: tuple[float, float] = (0.25, 0.35), constrained: bool = False,
           **subplots: Any) -> tuple[Any, Any]:
    """A figure of ``width`` × ``height`` inches and its ``rows`` × ``columns`` axes (a 2-D
    array; ``subplots`` go to ``Figure.subplots``, e.g. ``sharex``). By default the layout is
    fixed: ``margins`` (left, right, top, bottom) and ``space`` (wspace, hspace) as figure
    fractions, no layout engine (a tight or constrained layout draws every figure once more);
    ``constrained`` lets matplotlib's constrained layout place colour bars and long labels."""
    from matplotlib.figure import Figure

    if constrained:
        fig = Figure(figsize=(width, height), layout='constrained')
        return fig, fig.subplots(rows, columns, squeeze=False, **subplots)
    fig = Figure(figsize=(width, height))
    axes = fig.subplots(rows, columns, squeeze=False, **subplots)
    left, right, top, bottom = margins
    fig.subplots_adjust(left=left, right=right, top=top, bottom=bottom, wspace=space[0],
                        hspace=space[1])
    return fig, axes


def colours(names: list[str]) -> dict[str, Any]:
    """One colour of matplotlib's tab10 per name, in order."""
    from matplotlib import colormaps

    cmap = colormaps['tab10']
    return {name: cmap(i % 10) for i, name in enumerate(names)}


def log_scale(ax: Any) -> None:
    """A logarithmic y axis with minor ticks at 2 and 5 × each power of ten only (the default
    eight per decade, each a tick object laid out and drawn, were a third of a two-axes
    figure's cost); the default labels (minor ones too when the axis spans under a decade)."""
    from matplotlib.ticker import LogLocator

    ax.set_yscale('log')
    ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))


def save(fig: Any, path: Path) -> Path:
    """Write the figure as PNG at :data:`DPI`; returns ``path``."""
    fig.savefig(path, dpi=DPI)
    return path


def warm_up() -> None:
    """Import matplotlib and draw a small figure in memory (a log axis, markers, a bar, text
    with µ, Δ and °): the fonts and matplotlib's caches loaded, so that the first report
    figure drawn after it costs no more than the next ones (a worker's start)."""
    from io import BytesIO

    fig, axes = figure(2, 1.5)
    ax = axes[0, 0]
    ax.plot([1.0, 2.0], [1.0, 10.0], 'o', label='Δp µm')
    ax.bar([1.0], [3.0], 0.3, yerr=[1.0], capsize=2)
    ax.set_yscale('log')
    ax.set_title('angle °', fontsize=9)
    ax.legend(fontsize=7)
    fig.savefig(BytesIO(), format='png', dpi=DPI)
