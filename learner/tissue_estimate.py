"""What a personalised heart infers about its tissue: where it is abnormal, and how fast healthy tissue conducts.

A model with a tissue head (:mod:`learner.models.tissue_head`) reads each draw
of the heart's ``c`` as a per-node probability of abnormal tissue (scar core
or border zone) and a conduction velocity of the healthy tissue (m/s, along
fibres). :func:`estimate_tissue` averages ``samples`` draws: the probability
map is the mean of the draws' probabilities, the CV the mean of their CVs, and
each comes with its spread over the draws (a heart personalised from fewer or
noisier recordings has a wider one). The abnormal region is where the
probability reaches :data:`ABNORMAL_THRESHOLD`.

Scored against a simulated truth, :func:`tissue_scores` gives the Dice
coefficient of the abnormal region (the seed's DC, here against the tissue
itself rather than an activation map) and the relative CV error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from learner.graph.hierarchy import MeshHierarchy
from learner.metrics import dice
from learner.models.surrogate import MetaPNS, Posterior
from shared.errors import InputError
from shared.mesh import Mesh

__all__ = [
    "ABNORMAL_THRESHOLD",
    "TISSUE_SAMPLES",
    "TissueEstimate",
    "estimate_tissue",
    "tissue_scores",
    "write_tissue_vtk",
    "plot_tissue_estimate",
]

#: Probability from which a node counts as abnormal tissue.
ABNORMAL_THRESHOLD = 0.5
#: Draws of ``c`` a tissue estimate averages by default.
TISSUE_SAMPLES = 32


@dataclass
class TissueEstimate:
    """A heart's inferred tissue on its mesh's ``N`` nodes (module docstring)."""

    abnormal_probability: NDArray[np.float32]  # (N,) mean over draws
    abnormal_spread: NDArray[np.float32]  # (N,) std over draws
    cv_draws: NDArray[np.float64]  # (samples,) m/s
    mesh: Mesh

    @property
    def cv(self) -> float:
        """Conduction velocity of the healthy tissue (m/s): the mean over draws."""
        return float(self.cv_draws.mean())

    @property
    def cv_spread(self) -> float:
        """Its standard deviation over the draws of ``c`` (m/s)."""
        return float(self.cv_draws.std())

    @property
    def abnormal(self) -> NDArray[np.bool_]:
        """(N,) the abnormal region: probability at least :data:`ABNORMAL_THRESHOLD`."""
        return self.abnormal_probability >= ABNORMAL_THRESHOLD

    def arrays(self) -> dict[str, NDArray]:
        """The tissue file's arrays (docs/formats.md)."""
        return {
            "abnormal_probability": self.abnormal_probability,
            "abnormal_spread": self.abnormal_spread,
            "abnormal": self.abnormal,
            "cv_m_per_s": np.float64(self.cv),
            "cv_spread_m_per_s": np.float64(self.cv_spread),
            "cv_draws_m_per_s": self.cv_draws,
            "points": self.mesh.points,
            "cells": self.mesh.cells,
        }

    def summary(self) -> str:
        """One line: the CV with its spread and the abnormal share of the nodes."""
        return (
            f"healthy tissue conducts at {self.cv:.2f} +- {self.cv_spread:.2f} m/s; "
            f"{100 * self.abnormal.mean():.1f}% of the nodes read as scar core or border zone "
            f"(probability >= {ABNORMAL_THRESHOLD:g})"
        )


def estimate_tissue(
    model: MetaPNS,
    posterior: Posterior,
    hierarchy: MeshHierarchy,
    mesh: Mesh,
    samples: int = TISSUE_SAMPLES,
    seed: int = 0,
) -> TissueEstimate:
    """The tissue ``samples`` draws of ``c`` from ``posterior`` say (module docstring)."""
    if model.tissue_head is None:
        raise InputError(
            "this model infers no tissue: it was trained without a tissue head (model.tissue_head; "
            "specs/train-prior.toml trains one)"
        )
    if not 2 <= samples <= 10_000:
        raise InputError(f"tissue samples must be between 2 and 10000 draws of c, got {samples}")
    generator = torch.Generator().manual_seed(seed)
    probabilities, speeds = [], []
    with torch.no_grad():
        for _ in range(samples):
            logit, log_cv = model.tissue(posterior.sample(generator), hierarchy)
            probabilities.append(torch.sigmoid(logit).cpu().numpy())
            speeds.append(float(torch.exp(log_cv)))
    p = np.stack(probabilities)
    return TissueEstimate(p.mean(axis=0).astype(np.float32), p.std(axis=0).astype(np.float32), np.array(speeds), mesh)


def tissue_scores(estimate: TissueEstimate, abnormal: NDArray[np.bool_], cv: float) -> dict[str, float]:
    """Dice of the estimate's abnormal region against the true one (NaN where neither has any) and the relative
    CV error ``|cv_hat - cv| / cv`` against the true healthy CV (m/s)."""
    truth = np.asarray(abnormal, bool)
    if truth.shape != estimate.abnormal.shape:
        raise InputError(f"true abnormal mask has {truth.shape} nodes, the estimate {estimate.abnormal.shape}")
    both_empty = not truth.any() and not estimate.abnormal.any()
    return {
        "tissue_dice": float("nan") if both_empty else dice(estimate.abnormal, truth),
        "cv_error": abs(estimate.cv - cv) / cv,
        "cv": estimate.cv,
        "cv_true": float(cv),
    }


def write_tissue_vtk(estimate: TissueEstimate, path: str | Path) -> Path:
    """A ``.vtu`` of the mesh with ``abnormal_probability``, ``abnormal_spread`` and ``abnormal`` (0/1) per node."""
    import meshio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cells = estimate.mesh.cells
    kind = "tetra" if cells.shape[1] == 4 else "triangle"
    fields = {
        "abnormal_probability": estimate.abnormal_probability,
        "abnormal_spread": estimate.abnormal_spread,
        "abnormal": estimate.abnormal.astype(np.float32),
    }
    meshio.write(path, meshio.Mesh(estimate.mesh.points, [(kind, cells)], point_data=fields))
    return path


def plot_tissue_estimate(
    estimate: TissueEstimate, path: str | Path, truth: NDArray[np.bool_] | None = None, title: str = ""
) -> Path:
    """A PNG of the abnormal-tissue probability and its spread (and, given, the true abnormal nodes), front and
    back, titled with the CV."""
    from learner.plot import plot_activation_panels

    cols = [
        ("abnormal-tissue probability", estimate.abnormal_probability, "probability"),
        ("spread", estimate.abnormal_spread, "probability"),
    ]
    if truth is not None:
        cols.append(("true scar core + border", np.asarray(truth, np.float64), "probability"))
    row = title or f"CV {estimate.cv:.2f} +- {estimate.cv_spread:.2f} m/s"
    return plot_activation_panels(estimate.mesh.points, [(row, cols)], path)
