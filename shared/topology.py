"""Mesh topology both programs need: the faces of tetrahedra, equal rows grouped, the boundary faces."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["tet_faces", "group_rows", "boundary_faces"]

# Faces of tetrahedron (a, b, c, d) oriented outward when its volume is positive.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def tet_faces(tets: NDArray[np.integer]) -> NDArray[np.int32]:
    """All faces (4M, 3), outward-oriented for positively oriented tets."""
    return tets[:, _TET_FACES].reshape(-1, 3).astype(np.int32)


def group_rows(rows: NDArray[np.integer]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Group equal rows of a non-negative integer array, like ``np.unique(axis=0)``.

    Returns ``(inverse, counts)``: the group of each row (groups numbered in
    lexicographic row order) and the size of each group.

    Rows are packed into one int64 key each (see :func:`_packed_keys`), so one
    1-D sort replaces the far slower row-wise unique; rows too wide to pack
    are lexsorted instead.
    """
    rows = np.asarray(rows, dtype=np.int64)
    key = _packed_keys(list(rows.T))
    if key is not None:
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        return inverse.ravel(), counts
    order = np.lexsort(rows.T[::-1])
    ordered = rows[order]
    group = np.concatenate([[0], np.cumsum(np.any(ordered[1:] != ordered[:-1], axis=1))])
    inverse = np.empty(len(rows), dtype=np.int64)
    inverse[order] = group
    return inverse, np.bincount(group)


def boundary_faces(tets: NDArray[np.integer]) -> NDArray[np.int32]:
    """Faces that belong to exactly one tetrahedron, keeping their outward orientation.

    Each face is keyed by its sorted node triple ``a <= b <= c`` packed as
    ``(a N + b) N + c`` (``N`` = largest node index + 1); one sort of the keys finds
    the faces whose key occurs once (much faster than a row-wise
    :func:`numpy.unique`). Meshes too large to pack
    (``N^3 >= 2^62``) fall back to :func:`group_rows`.
    """
    faces = tet_faces(tets)
    a, b, c = faces.T.astype(np.int64)
    # Sorting network for three columns: much faster than np.sort(axis=1) on short rows.
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    key = _packed_keys([lo, a + b + c - lo - hi, hi])
    if key is None:
        inverse, counts = group_rows(np.sort(faces, axis=1))
        return faces[counts[inverse] == 1]
    order = np.argsort(key)
    ordered = key[order]
    differs = ordered[1:] != ordered[:-1]
    once = np.ones(len(key), dtype=bool)
    once[1:] = differs
    once[:-1] &= differs
    keep = np.zeros(len(key), dtype=bool)
    keep[order[once]] = True
    return faces[keep]


def _packed_keys(columns: list[NDArray[np.int64]]) -> NDArray[np.int64] | None:
    """One int64 per row, equal exactly when the rows are: ``sum_j r_j N^(k-1-j)``.

    ``N`` is the largest entry plus one and ``k`` the number of columns;
    ``None`` when ``N^k >= 2^62`` (the key could overflow).
    """
    n_rows = len(columns[0]) if columns else 0
    base = max(int(col.max()) for col in columns) + 1 if n_rows else 1
    if base ** len(columns) >= 2**62:
        return None
    key = np.zeros(n_rows, dtype=np.int64)
    for col in columns:
        key = key * base + col
    return key
