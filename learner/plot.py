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
from matplotlib.lines import Line2D
from numpy.typing import NDArray

__all__ = ["plot_activation_panels", "plot_context_curves", "plot_training_curves"]

#: The two views of every map: (elevation, azimuth, name).
_VIEWS = ((12.0, 0.0, "front"), (12.0, 180.0, "back"))
#: Colour map and label of each scale a column can use; columns of one scale share its range.
SCALES = {
    "activation": ("turbo_r", "activation time (ms)"),
    "spread": ("viridis", "spread over draws (ms)"),
    "error": ("magma_r", "|prediction - truth| (ms)"),
    "probability": ("Reds", "probability of scar core or border zone"),
}
#: Scales whose colours run over a fixed range, whatever the values.
FIXED_TOP = {"probability": 1.0}


def plot_activation_panels(
    points: NDArray,
    rows: Sequence[tuple[str, Sequence[tuple[str, NDArray] | tuple[str, NDArray, str]]]],
    path: str | Path,
    vmax: float | None = None,
    sites: Sequence[NDArray | None] | None = None,
) -> Path:
    """A grid of maps on the mesh: one row per case, one column per map, each from the front and the back.

    ``rows`` is ``[(row title, [(column title, values per node[, scale]), ...]), ...]``; a column's scale
    (:data:`SCALES`, default ``"activation"``) sets its colours, and every column of one scale shares one
    range (from 0 to ``vmax`` for activation times, else the largest value) and one colour bar. NaN (never
    activated) is drawn grey; ``sites[r]`` (a point in mm) marks row ``r``'s paced site with a star.
    """
    columns = [(col[0], col[1], col[2] if len(col) > 2 else "activation") for _, cols in rows for col in cols]
    top = {}
    for _, values, scale in columns:
        peak = float(np.nanmax(values)) if np.isfinite(values).any() else 0.0
        top[scale] = max(top.get(scale, 0.0), peak)
    if vmax is not None:
        top["activation"] = vmax
    top |= {scale: value for scale, value in FIXED_TOP.items() if scale in top}
    size = float(np.clip(6000.0 / len(points), 1.0, 12.0))
    n_cols = max(len(cols) for _, cols in rows) * len(_VIEWS)
    height = 2.8 * len(rows) + 1.0
    fig = Figure(figsize=(max(2.6 * n_cols, 7.0), height))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.0, right=1.0, top=1.0 - 0.5 / height, bottom=0.95 / height, wspace=0.0, hspace=0.15)
    drawn = {}
    for r, (row_title, cols) in enumerate(rows):
        for c, col in enumerate(cols):
            col_title, values = col[0], np.asarray(col[1], np.float64)
            scale = col[2] if len(col) > 2 else "activation"
            for v, (elev, azim, view) in enumerate(_VIEWS):
                ax = fig.add_subplot(len(rows), n_cols, r * n_cols + c * len(_VIEWS) + v + 1, projection="3d")
                finite = np.isfinite(values)
                ax.scatter(*points[~finite].T, s=size, c="0.8", depthshade=False)
                cmap, _ = SCALES[scale]
                drawn[scale] = ax.scatter(
                    *points[finite].T,
                    s=size,
                    c=values[finite],
                    cmap=cmap,
                    vmin=0,
                    vmax=top[scale] or 1.0,
                    depthshade=False,
                )
                if sites is not None and sites[r] is not None:
                    ax.scatter(*np.asarray(sites[r]).reshape(3, 1), s=160, marker="*", c="k", depthshade=False)
                ax.view_init(elev, azim)
                ax.set_axis_off()
                ax.set_box_aspect(np.ptp(points, axis=0))
                title = f"{col_title}, {view}"
                ax.set_title(f"{row_title}\n{title}" if c == 0 and v == 0 else title, fontsize=9)
    bar_height = 0.12 / height
    for i, (scale, mappable) in enumerate(drawn.items()):  # one horizontal colour bar per scale, along the bottom
        cax = fig.add_axes((0.3 + 0.36 * i, 0.42 / height, 0.3, bar_height))
        fig.colorbar(mappable, cax=cax, orientation="horizontal", label=SCALES[scale][1])
    handles = []
    if any(not np.isfinite(np.asarray(values, np.float64)).all() for _, values, _ in columns):
        handles.append(Line2D([], [], ls="", marker="o", color="0.8", label="never activated"))
    if sites is not None:
        handles.append(Line2D([], [], ls="", marker="*", color="k", ms=12, label="paced site"))
    fig.legend(handles=handles, loc="lower left", fontsize=9, frameon=False)
    path = Path(path)
    fig.savefig(path, dpi=120)
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
