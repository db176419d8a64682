"""Folded and self-overlapping surfaces: triangles that cross triangles they share no node with.

A heart's surface (a triangle mesh's cells, a tetrahedral mesh's boundary
faces) never passes through itself; one that does (a wall pushed through the
opposite wall, two overlapping parts merged) would be read as a heart of
another shape, e.g. a folded left ventricle as two cavities. Candidate pairs
come from a k-d tree of the triangles' centroids (pairs closer than the sum of
their circumradii), then each pair's six edge-triangle crossings are tested
(Möller-Trumbore), all vectorised. Touching is not crossing: an edge must pass
through a triangle's interior, strictly between its end points.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.topology import boundary_faces

__all__ = ["crossing_triangles", "refuse_folds"]

#: Relative margin of the crossing test: an edge touching a triangle's border, or ending on it, does not cross.
_EPS = 1e-9


def _edges_cross(p0: NDArray, p1: NDArray, a: NDArray, b: NDArray, c: NDArray) -> NDArray[np.bool_]:
    """Whether each segment ``p0 -> p1`` passes through the interior of triangle ``(a, b, c)`` (rows)."""
    e1, e2, d = b - a, c - a, p1 - p0
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
    ok = np.abs(det) > _EPS * scale  # not parallel to the triangle's plane
    f = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    s = p0 - a
    u = f * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = f * np.einsum("ij,ij->i", d, q)
    t = f * np.einsum("ij,ij->i", e2, q)
    return ok & (u > _EPS) & (v > _EPS) & (u + v < 1 - _EPS) & (t > _EPS) & (t < 1 - _EPS)


def crossing_triangles(points: NDArray[np.float64], tris: NDArray[np.integer]) -> NDArray[np.int64]:
    """Pairs ``(i, j)``, ``i < j``, of triangles that share no edge and cross each other: an edge of one passes
    through the other's interior. Of a pair sharing one node (parts merged at a seam), only the edges opposite
    that node can (the others meet the other triangle at the node alone)."""
    tris = np.asarray(tris, np.int64)
    corners = points[tris]  # (T, 3, 3)
    centroids = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max(axis=1)
    pairs = cKDTree(centroids).query_pairs(2 * float(radius.max(initial=0.0)), output_type="ndarray")
    if not len(pairs):
        return np.zeros((0, 2), np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    near = np.linalg.norm(centroids[i] - centroids[j], axis=1) <= radius[i] + radius[j]
    shared = (tris[i][:, :, None] == tris[j][:, None, :]).any(axis=2).sum(axis=1)  # nodes the pair shares
    i, j = i[near & (shared < 2)], j[near & (shared < 2)]
    crossed = np.zeros(len(i), bool)
    for first, second in ((i, j), (j, i)):
        a, b, c = (corners[second][:, k] for k in range(3))
        on_shared = (tris[first][:, :, None] == tris[second][:, None, :]).any(axis=2)  # (P, 3) per corner
        for k in range(3):
            free = ~(on_shared[:, k] | on_shared[:, (k + 1) % 3])  # the edge does not end at the shared node
            crossed |= free & _edges_cross(corners[first][:, k], corners[first][:, (k + 1) % 3], a, b, c)
    found = np.stack([i[crossed], j[crossed]], axis=1)
    return np.sort(found, axis=1)[np.lexsort((found.max(axis=1), found.min(axis=1)))]


def refuse_folds(mesh: Mesh, source: str) -> None:
    """Raise :class:`MeshError` when ``mesh``'s surface passes through itself (module docstring)."""
    tris = mesh.cells if mesh.cell_type == "triangle" else boundary_faces(mesh.cells)
    crossing = crossing_triangles(mesh.points, tris)
    if len(crossing):
        where = mesh.points[tris[crossing[0]]].reshape(-1, 3).mean(axis=0)
        raise MeshError(
            f"{source}: its surface passes through itself ({len(crossing)} pair(s) of surface triangles cross, "
            f"the first near ({', '.join(f'{x:.1f}' for x in where)}) mm): a folded or self-overlapping surface "
            "is no heart's; fill it with tetrahedra (--nodes N --kind tetra: fTetWild rebuilds the surface) or "
            "repair it first"
        )
