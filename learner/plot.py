"""Figures of the surrogate's results: activation maps, accuracy vs context size, training curves.

Built on :class:`matplotlib.figure.Figure` with the Agg canvas (no pyplot, no
display, the caller's backend untouched), like ``simgen.plot``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

__all__ = ["plot_activation_panels", "plot_context_curves", "plot_training_curves"]

_VIEWS = ((12.0, 0.0), (12.0, 180.0))


def plot_activation_panels(
    points: NDArray,
    rows: Sequence[tuple[str, Sequence[tuple[str, NDArray]]]],
    path: str | Path,
    vmax: float | None = None,
) -> Path:
    """A grid of activation-time maps: one row per case, one column per map, front and back views.

    ``rows`` is ``[(row title, [(column title, activation ms per node), ...]), ...]``;
    NaN (never activated) is drawn grey. All panels share one colour scale.
    """
    maps = [m for _, cols in rows for _, m in cols]
    top = vmax if vmax is not None else float(np.nanmax([np.nanmax(m) if np.isfinite(m).any() else 0 for m in maps]))
    n_cols = max(len(cols) for _, cols in rows) * len(_VIEWS)
    fig = Figure(figsize=(2.2 * n_cols, 2.4 * len(rows) + 0.6))
    FigureCanvasAgg(fig)
    for r, (row_title, cols) in enumerate(rows):
        for c, (col_title, values) in enumerate(cols):
            for v, (elev, azim) in enumerate(_VIEWS):
                ax = fig.add_subplot(len(rows), n_cols, r * n_cols + c * len(_VIEWS) + v + 1, projection="3d")
                finite = np.isfinite(values)
                ax.scatter(*points[~finite].T, s=2, c="0.75", depthshade=False)
                sc = ax.scatter(
                    *points[finite].T, s=3, c=values[finite], cmap="turbo_r", vmin=0, vmax=top, depthshade=False
                )
                ax.view_init(elev, azim)
                ax.set_axis_off()
                ax.set_box_aspect(np.ptp(points, axis=0))
                if v == 0:
                    ax.set_title(f"{row_title}\n{col_title}" if c == 0 else col_title, fontsize=8)
    fig.colorbar(sc, ax=fig.axes, shrink=0.6, label="activation time (ms)")
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_context_curves(
    by_size: Mapping[str, Mapping[str, Mapping[str, Mapping[str, float]]]],
    path: str | Path,
    metrics: Sequence[str] = ("mse", "cc_spatial", "cc_temporal", "dc"),
) -> Path:
    """Fig. 3 of the paper: target accuracy against context size, one line per model.

    ``by_size[model][K][metric] = {"mean": m, "std": s}`` (target set).
    """
    fig = Figure(figsize=(3.2 * len(metrics), 3.0))
    FigureCanvasAgg(fig)
    for i, metric in enumerate(metrics):
        ax = fig.add_subplot(1, len(metrics), i + 1)
        for model, sizes in by_size.items():
            ks = sorted(sizes, key=int)
            mean = np.array([sizes[k][metric]["mean"] for k in ks])
            std = np.array([sizes[k][metric]["std"] for k in ks])
            x = np.array([int(k) for k in ks])
            ax.errorbar(x, mean, yerr=std, marker="o", capsize=3, label=model)
        ax.set_xlabel("context size")
        ax.set_title(metric)
        ax.set_xticks(range(1, 1 + max(int(k) for s in by_size.values() for k in s)))
        ax.grid(alpha=0.3)
    fig.axes[0].legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_training_curves(runs: Mapping[str, Sequence[Mapping[str, float]]], path: str | Path) -> Path:
    """Validation target MSE (log scale) and mean training target MSE against epoch, one colour per run.

    ``runs[label]`` is a run's ``log.jsonl`` rows (``epoch``, ``target_mse`` and,
    on validation epochs, ``val_target_mse``).
    """
    fig = Figure(figsize=(6.4, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for i, (label, rows) in enumerate(runs.items()):
        colour = f"C{i}"
        val = [(r["epoch"], r["val_target_mse"]) for r in rows if r.get("val_target_mse") is not None]
        ax.plot([r["epoch"] for r in rows], [r["target_mse"] for r in rows], color=colour, alpha=0.35, lw=1)
        if val:
            ax.plot(*zip(*val), color=colour, marker="o", ms=3, label=f"{label}: validation")
    ax.plot([], [], color="grey", alpha=0.35, label="training (mean per epoch)")
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("target MSE")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path
