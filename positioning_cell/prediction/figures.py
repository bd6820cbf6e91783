"""Figures (PNG, matplotlib Agg) of the accuracy prediction: workspace maps, the angle
distribution with its fits, and the stacked-stage curves of seed 003. People read them, so
they show µm, mm, µrad and mrad, and say so."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from positioning_cell.plotting import figure, save
from positioning_cell.prediction.angular import AngleFits, Strategy
from positioning_cell.prediction.maps import WorkspaceMaps

FloatArray = NDArray[np.float64]


def plot_workspace_maps(maps: WorkspaceMaps, out_dir: Path) -> list[Path]:
    """Write ``map_position.png`` and ``map_orientation.png`` (worst case, 3σ, dominant kind of
    source) into ``out_dir``; returns the paths."""
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm, ListedColormap

    extent = (maps.x[0] * 1e3, maps.x[-1] * 1e3, maps.y[0] * 1e3, maps.y[-1] * 1e3)
    colours = colormaps['tab10'](np.arange(len(maps.kinds)))
    kind_cmap = ListedColormap(colours).with_extremes(under='white')
    kind_norm = BoundaryNorm(np.arange(len(maps.kinds) + 1) - 0.5, len(maps.kinds))
    paths = []
    for what, worst, sigma3, dominant, scale, unit in (
            ('position', maps.worst_position, maps.sigma3_position, maps.dominant_position,
             1e6, 'µm'),
            ('orientation', maps.worst_orientation, maps.sigma3_orientation,
             maps.dominant_orientation, 1e3, 'mrad')):
        fig, grid = figure(16, 4.8, 1, 3, constrained=True)
        axes = grid[0]
        for ax, data, title in ((axes[0], worst, 'worst case (seed 004 eq. 15)'),
                                (axes[1], sigma3, '3σ (linear model)')):
            im = ax.imshow(data * scale, origin='lower', extent=extent, cmap='viridis')
            fig.colorbar(im, ax=ax, label=f'{what} error ({unit})')
            ax.set_title(f'{what} error: {title}')
        im = axes[2].imshow(np.where(dominant < 0, -1, dominant), origin='lower', extent=extent,
                            cmap=kind_cmap, norm=kind_norm)
        bar = fig.colorbar(im, ax=axes[2], ticks=np.arange(len(maps.kinds)))
        bar.ax.set_yticklabels(list(maps.kinds))
        axes[2].set_title(f'dominant source of {what} variance')
        for ax in axes:
            ax.set_xlabel('platform x (mm, base frame)')
            ax.set_ylabel('platform y (mm, base frame)')
        fig.suptitle(f'3-UPS predicted {what} accuracy at z = {maps.z * 1e3:.1f} mm '
                     '(white: outside the limits)')
        paths.append(save(fig, out_dir / f'map_{what}.png'))
    return paths


def plot_angle_fits(angles: FloatArray, fits: AngleFits, path: Path,
                    title: str = 'platform-normal angle error') -> Path:
    """Histogram of angles (N,) rad with the fitted Rice and GEV densities, in mrad."""
    fig, grid = figure(7.5, 4.8, constrained=True)
    ax = grid[0, 0]
    data = angles[np.isfinite(angles)] * 1e3
    ax.hist(data, bins=120, density=True, color='0.75', label=f'Monte Carlo ({data.size} samples)')
    grid = np.linspace(0.0, float(np.quantile(data, 0.9995)), 400)
    for fit, style in ((fits.rice, '-'), (fits.gev, '--')):
        pdf = fit.frozen().pdf(grid * 1e-3) * 1e-3
        ax.plot(grid, pdf, style, lw=2,
                label=f'{fit.name} fit, KS D = {fit.ks_statistic:.4f}')
    ax.set_xlabel('angle between platform normal and nominal (mrad)')
    ax.set_ylabel('probability density (1/mrad)')
    ax.set_title(title)
    ax.legend()
    return save(fig, path)


def plot_stacked_stages(curves: Mapping[int, Mapping[Strategy, FloatArray]], path: Path) -> Path:
    """Mean and standard deviation of the stack angle (rad → mrad) against the number of parts,
    one panel per seed 003 example; ``curves[example][strategy]`` is (runs, parts)."""
    fig, axes = figure(6.5 * len(curves), 4.8, 1, len(curves), constrained=True)
    for ax, (example, by_strategy) in zip(axes[0], curves.items(), strict=True):
        for strategy, angles in by_strategy.items():
            parts = np.arange(1, angles.shape[1] + 1)
            line = ax.plot(parts, angles.mean(axis=0) * 1e3, 'o-',
                           label=f'{strategy.value} ({angles.shape[0]} runs): mean')[0]
            ax.plot(parts, angles.std(axis=0) * 1e3, 's--', color=line.get_color(),
                    label=f'{strategy.value}: std')
        ax.set_xlabel('number of parts n')
        ax.set_ylabel('stack angle error (mrad)')
        ax.set_title(f'seed 003 example {example}: stacked parts, k clocking positions')
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    return save(fig, path)
