"""Structured strip (triangles) and slab (tetrahedra) meshes for verification runs.

Planar fronts on these meshes have the analytic speed of the cable equation,
so conduction velocity and its convergence can be tested directly.
"""

from __future__ import annotations

import numpy as np

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.topology import boundary_faces

__all__ = ["strip", "slab"]


def _grid_counts(extent: tuple[float, ...], spacing: float) -> list[int]:
    if not np.isfinite(spacing) or spacing <= 0:
        raise MeshError(f"spacing must be > 0, got {spacing}")
    if min(extent) <= 0:
        raise MeshError(f"extents must be > 0, got {extent}")
    return [max(1, int(round(e / spacing))) for e in extent]


def strip(length: float, width: float, spacing: float) -> Mesh:
    """Rectangle ``[0, length] x [0, width]`` in the z = 0 plane, right triangles of leg ``spacing``."""
    nx, ny = _grid_counts((length, width), spacing)
    x, y = np.meshgrid(np.linspace(0, length, nx + 1), np.linspace(0, width, ny + 1), indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    idx = np.arange(points.shape[0]).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Mesh(points, cells, {"surface": np.arange(len(points))}, name="strip")


# Kuhn (Freudenthal) split of a unit cube into six tetrahedra along its main diagonal;
# corners are numbered by bits (x, y, z), so all cubes split conformingly.
_KUHN = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])


def slab(length: float, width: float, depth: float, spacing: float) -> Mesh:
    """Box ``[0, length] x [0, width] x [0, depth]`` split into Kuhn tetrahedra of edge ``spacing``."""
    nx, ny, nz = _grid_counts((length, width, depth), spacing)
    axes = [np.linspace(0, e, n + 1) for e, n in zip((length, width, depth), (nx, ny, nz))]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    idx = np.arange(points.shape[0]).reshape(nx + 1, ny + 1, nz + 1)
    corners = np.stack(
        [idx[i : nx + i, j : ny + j, k : nz + k].ravel() for k in (0, 1) for j in (0, 1) for i in (0, 1)],
        axis=1,
    )  # corner bit order: x fastest
    cells = corners[:, _KUHN].reshape(-1, 4)
    p = points[cells]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    cells[vol < 0] = cells[vol < 0][:, [0, 2, 1, 3]]
    surface = np.unique(boundary_faces(cells))
    return Mesh(points, cells, {"surface": surface}, name="slab")
