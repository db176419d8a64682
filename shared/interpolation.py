"""P1 interpolation between meshes: the value of a nodal field at arbitrary points, as a sparse matrix.

A P1 field on a mesh is linear inside each cell, so its value at a point ``x``
inside cell ``c`` is ``sum_k lambda_k(x) f(v_k)`` with the barycentric
coordinates ``lambda`` of ``x`` in ``c``. :func:`interpolation_matrix` finds,
for every query point, the cell that holds it (tetrahedra), or the triangle it
projects onto (surfaces), and returns the ``(Q, N)`` matrix of those weights,
so a whole simulation moves between meshes in one sparse-dense product:
``u_query = W @ u``. A point outside the mesh (the surfaces of two
discretisations of one heart differ by a fraction of an edge) takes the
nearest point of the nearest candidate cell: its barycentric coordinates are
clipped to the cell and renormalised.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from shared.errors import InputError

__all__ = ["interpolation_matrix", "barycentric"]

#: Candidate cells (nearest centroids) examined per query point; more are tried for points left outside.
CANDIDATES = 16
#: Most candidate cells examined for a point outside the mesh (the search widens 4x once).
MAX_CANDIDATES = 64


def barycentric(corners: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Barycentric coordinates ``(..., k)`` of points ``x`` (..., 3) in simplices ``corners`` (..., k, 3).

    Tetrahedra (k = 4) solve the 3x3 system; triangles (k = 3) use the
    least-squares coordinates, i.e. those of ``x`` projected onto the
    triangle's plane. Degenerate simplices give NaN.
    """
    corners = np.asarray(corners, np.float64)
    x = np.asarray(x, np.float64)
    edges = corners[..., 1:, :] - corners[..., :1, :]  # (..., k-1, 3)
    rhs = x - corners[..., 0, :]
    gram = edges @ np.swapaxes(edges, -1, -2)  # (..., k-1, k-1): normal equations (exact for tetrahedra)
    proj = (edges @ rhs[..., None])[..., 0]
    det = np.linalg.det(gram)
    ok = np.abs(det) > 1e-30 * np.maximum(1.0, np.abs(gram).max(axis=(-1, -2)) ** gram.shape[-1])
    safe = np.where(ok[..., None, None], gram, np.eye(gram.shape[-1]))
    tail = np.linalg.solve(safe, proj[..., None])[..., 0]
    lam = np.concatenate([1.0 - tail.sum(axis=-1, keepdims=True), tail], axis=-1)
    lam[~ok] = np.nan
    return lam


def interpolation_matrix(
    points: ArrayLike, cells: ArrayLike, query: ArrayLike, candidates: int = CANDIDATES
) -> sp.csr_matrix:
    """Sparse ``(Q, N)`` matrix of P1 weights: row ``q`` evaluates a nodal field of the mesh at ``query[q]``.

    Parameters
    ----------
    points : (N, 3) node coordinates of the mesh the field lives on.
    cells : (M, 4) tetrahedra or (M, 3) triangles (node ids).
    query : (Q, 3) points to evaluate at.
    candidates : cells examined per point (by centroid distance) before the
        search widens for points not yet inside a cell.

    Each row holds at most ``k`` (4 or 3) non-negative weights summing to 1.
    """
    points = np.asarray(points, np.float64)
    cells = np.asarray(cells, np.int64)
    query = np.asarray(query, np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or query.ndim != 2 or query.shape[1] != 3:
        raise InputError(f"points and query must be (N, 3) and (Q, 3), got {points.shape} and {query.shape}")
    if cells.ndim != 2 or cells.shape[1] not in (3, 4) or len(cells) == 0:
        raise InputError(f"cells must be a non-empty (M, 4) or (M, 3) array, got {cells.shape}")
    if not (np.isfinite(points).all() and np.isfinite(query).all()):
        raise InputError("points and query must be finite")
    k = cells.shape[1]
    tree = cKDTree(points[cells].mean(axis=1))
    scale = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    q = len(query)
    best_lam = np.zeros((q, k))
    best_cell = np.zeros(q, np.int64)
    best_gap = np.full(q, np.inf)  # distance from the point to its place in the cell (0 inside a tetrahedron)
    todo = np.arange(q)
    width = min(candidates, len(cells))
    while len(todo):
        _, near = tree.query(query[todo], k=width)
        near = near.reshape(len(todo), width)
        corners = points[cells[near]]  # (T, width, k, 3)
        lam = np.clip(barycentric(corners, query[todo, None, :]), 0.0, None)
        lam /= lam.sum(axis=2, keepdims=True)
        gap = np.linalg.norm(np.einsum("twk,twkd->twd", lam, corners) - query[todo, None, :], axis=2)
        gap[~np.isfinite(gap)] = np.inf  # degenerate cells
        pick = gap.argmin(axis=1)
        rows = np.arange(len(todo))
        better = gap[rows, pick] < best_gap[todo]
        sel = todo[better]
        best_lam[sel] = lam[rows, pick][better]
        best_cell[sel] = near[rows, pick][better]
        best_gap[sel] = gap[rows, pick][better]
        if k == 3 or width >= min(len(cells), MAX_CANDIDATES):
            break  # a surface point lies off every triangle's plane: no test tells it is found
        todo = todo[best_gap[todo] > 1e-9 * scale]  # outside every cell seen so far: widen the search
        width = min(4 * width, len(cells), MAX_CANDIDATES)
    rows = np.repeat(np.arange(q), k)
    return sp.csr_matrix((best_lam.ravel(), (rows, cells[best_cell].ravel())), shape=(q, len(points)))
