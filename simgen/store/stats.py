"""Normalisation statistics of ``u`` and ``activation``: per-chunk moments, combined exactly.

A task writes its chunk's moments (count, sum, sum of squares, min, max of
the finite values, :data:`shared.schema.MOMENTS`) next to its data, computed
from the very arrays it writes; the end of a build combines them into mean,
std, min and max per subject and for the store. Each chunk's sums run in one
fixed order and the combination uses :func:`math.fsum` (exactly rounded,
independent of order), so statistics are the same whichever workers ran the
chunks, in whatever order, and whatever subjects were added later.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from shared.schema import MOMENT_VARIABLES, MOMENTS

__all__ = ["chunk_moments", "combine", "statistics"]


@njit(cache=True)
def _moments(values):  # pragma: no cover - compiled
    """Count, sum, sum of squares, min and max of the finite entries of a 1-D array, in order, in float64."""
    count, total, squares, lo, hi = 0, 0.0, 0.0, np.inf, -np.inf
    for v in values:
        if np.isfinite(v):
            x = np.float64(v)
            count += 1
            total += x
            squares += x * x
            lo = min(lo, x)
            hi = max(hi, x)
    return count, total, squares, lo, hi


def chunk_moments(u: NDArray, activation: NDArray) -> NDArray[np.float64]:
    """The ``(variable, moment)`` moments of one chunk's ``u`` and ``activation``."""
    return np.array([_moments(np.ravel(u)), _moments(np.ravel(activation))], np.float64)


def combine(moments: NDArray[np.float64]) -> dict:
    """``count``, ``mean``, ``std`` (population), ``min`` and ``max`` of the values behind rows of ``moments``.

    ``moments``: ``(k, len(MOMENTS))``, one row per chunk. Without any value the
    four statistics are ``None``.
    """
    col = dict(zip(MOMENTS, np.asarray(moments, np.float64).T))
    count = int(math.fsum(col["count"]))
    if count == 0:
        return {"count": 0, "mean": None, "std": None, "min": None, "max": None}
    mean = math.fsum(col["sum"]) / count
    variance = max(math.fsum(col["sum_sq"]) / count - mean * mean, 0.0)
    return {
        "count": count,
        "mean": mean,
        "std": math.sqrt(variance),
        "min": float(col["min"].min()),
        "max": float(col["max"].max()),
    }


def statistics(moments: NDArray[np.float64]) -> dict[str, dict]:
    """Statistics per variable (``u``, ``activation``) from ``(k, variable, moment)`` chunk moments."""
    return {name: combine(moments[:, i]) for i, name in enumerate(MOMENT_VARIABLES)}
