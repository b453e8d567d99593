"""Figures of learned parameter distributions (the GoFlow paper's Fig. 2 for Toy2D) and of sweeps.

The figures take what they draw (samplers, a sweep's summary), never a run folder: loading runs is
`learning.experiment`'s (`load_run`), which calls these.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

import assembly  # noqa: F401  (registers the environment ids)

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def plot_toy2d_densities(
    env_id: str, env_kwargs: Mapping[str, Any], samplers: Mapping[str, Any], path: Path, grid: int = 120
) -> Figure:
    """One panel per method of `samplers` (method -> a sampler with `log_prob`, e.g. a run's final
    one): its density over the 2-D box of env `env_id` (made with `env_kwargs`), the feasible set's
    outline on top; a first panel shows the feasible set itself. Written to `path` (a PNG).
    Returns the matplotlib Figure (made without pyplot: no backend is chosen or switched)."""
    from matplotlib.figure import Figure

    env = gymnasium.make(env_id, **env_kwargs).unwrapped
    lo, hi = env.space.low, env.space.high
    xs, ys = np.linspace(lo[0], hi[0], grid), np.linspace(lo[1], hi[1], grid)
    X, Y = np.meshgrid(xs, ys)
    points = np.stack([X.ravel(), Y.ravel()], axis=1)
    feasible = env.feasible_set(points).reshape(grid, grid)
    methods = list(samplers)
    fig = Figure(figsize=(3 * (len(methods) + 1), 3.2))
    axes = fig.subplots(1, len(methods) + 1)
    extent = (lo[0], hi[0], lo[1], hi[1])
    axes[0].imshow(feasible, origin="lower", extent=extent, cmap="Greens")
    axes[0].set_title("feasible set")
    for ax, method in zip(axes[1:], methods):
        sampler = samplers[method]
        logp = np.asarray(sampler.log_prob(points), dtype=float)
        density = np.exp(np.where(np.isfinite(logp), logp, -np.inf))
        ax.imshow(
            density.reshape(grid, grid),
            origin="lower",
            extent=extent,
            cmap="viridis",
            vmin=0.0,
            vmax=max(float(np.percentile(density, 99.5)), 1e-12),
        )  # spikes clipped
        if hasattr(sampler, "point"):  # a point mass (NoDR): mark it
            ax.plot(*np.asarray(sampler.point)[:2], "r*", markersize=12)
        ax.contour(X, Y, feasible.astype(float), levels=[0.5], colors="w", linewidths=0.8)
        ax.set_title(method)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return fig


def plot_sweep(sweep: dict, path: Path) -> Figure:
    """Final uniform-box success (mean +- s.e. over seeds) against each swept value of one option;
    written to `path` (a PNG). Returns the matplotlib Figure (made without pyplot)."""
    from matplotlib.figure import Figure

    rows = sweep["rows"]
    labels = [str(r["value"]) for r in rows]
    fig = Figure(figsize=(5.0, 3.4))
    ax = fig.subplots()
    ax.errorbar(
        range(len(rows)),
        [r["final_success_mean"] for r in rows],
        yerr=[r["final_success_se"] for r in rows],
        fmt="o-",
        capsize=4,
    )
    ax.set_xticks(range(len(rows)), labels)
    ax.set_xlabel(f"{sweep['method']}: {sweep['param']}")
    ax.set_ylabel("final success on the uniform box")
    ax.set_title(f"{sweep['env']}, {rows[0]['seeds']} seed(s) per value", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return fig


__all__ = ["plot_sweep", "plot_toy2d_densities"]
