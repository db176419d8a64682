"""Whether rays hit a triangle surface, through a uniform grid of the triangles (numba).

:func:`rays_hit` answers, for each ray ``origin + t direction`` (``t > 0``),
whether it hits any triangle. The triangles are binned into a uniform grid
by their bounding boxes (about :data:`TRIANGLES_PER_CELL` per cell) and each
ray walks the cells it crosses (Amanatides and Woo's traversal), testing
the triangles binned there (Moller-Trumbore) until one is hit: a surface of
F triangles costs about F times the cells a ray crosses, not F squared, so
surfaces of tens of thousands of nodes are labelled as they are.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["TRIANGLES_PER_CELL", "rays_hit"]

#: Triangles per grid cell the grid resolution aims at.
TRIANGLES_PER_CELL = 4.0


def rays_hit(origins: NDArray, directions: NDArray, triangles: NDArray) -> NDArray[np.bool_]:
    """Whether each ray ``origins[i] + t directions[i]`` (t > 0) hits any of ``triangles`` (F, 3, 3)."""
    triangles = np.ascontiguousarray(triangles, dtype=np.float64)
    lo = triangles.reshape(-1, 3).min(axis=0)
    hi = triangles.reshape(-1, 3).max(axis=0)
    extent = np.maximum(hi - lo, 1e-9)
    cell = (np.prod(extent) * TRIANGLES_PER_CELL / max(len(triangles), 1)) ** (1 / 3)
    cell = max(cell, float(extent.max()) / 256)
    shape = np.maximum(np.ceil(extent / cell), 1).astype(np.int64)
    start, members = _bin(triangles, lo, cell, shape)
    return _cast(
        np.ascontiguousarray(origins, dtype=np.float64),
        np.ascontiguousarray(directions, dtype=np.float64),
        triangles,
        lo,
        cell,
        shape,
        start,
        members,
    )


@njit(cache=True)
def _cell_range(tri: NDArray, lo: NDArray, cell: float, shape: NDArray) -> NDArray:  # pragma: no cover
    """Lowest and highest grid cell (2, 3) of a triangle's bounding box."""
    out = np.empty((2, 3), dtype=np.int64)
    for k in range(3):
        a = min(tri[0, k], tri[1, k], tri[2, k])
        b = max(tri[0, k], tri[1, k], tri[2, k])
        out[0, k] = min(max(int((a - lo[k]) / cell), 0), shape[k] - 1)
        out[1, k] = min(max(int((b - lo[k]) / cell), 0), shape[k] - 1)
    return out


@njit(cache=True)
def _bin(triangles: NDArray, lo: NDArray, cell: float, shape: NDArray) -> tuple:  # pragma: no cover
    """Triangles of each cell as CSR arrays ``(start, members)``, cells numbered x fastest."""
    n_cells = shape[0] * shape[1] * shape[2]
    count = np.zeros(n_cells + 1, dtype=np.int64)
    for f in range(len(triangles)):
        r = _cell_range(triangles[f], lo, cell, shape)
        for i in range(r[0, 0], r[1, 0] + 1):
            for j in range(r[0, 1], r[1, 1] + 1):
                for k in range(r[0, 2], r[1, 2] + 1):
                    count[1 + i + shape[0] * (j + shape[1] * k)] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    members = np.empty(start[-1], dtype=np.int64)
    for f in range(len(triangles)):
        r = _cell_range(triangles[f], lo, cell, shape)
        for i in range(r[0, 0], r[1, 0] + 1):
            for j in range(r[0, 1], r[1, 1] + 1):
                for k in range(r[0, 2], r[1, 2] + 1):
                    c = i + shape[0] * (j + shape[1] * k)
                    members[fill[c]] = f
                    fill[c] += 1
    return start, members


@njit(cache=True)
def _hits_triangle(o: NDArray, d: NDArray, tri: NDArray) -> bool:  # pragma: no cover
    """Moller-Trumbore: whether ``o + t d`` (t > 0) crosses the triangle (scalar arithmetic, no allocation)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    e1x, e1y, e1z = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    e2x, e2y, e2z = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    dx, dy, dz = d[0], d[1], d[2]
    hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if abs(det) < 1e-12:
        return False
    sx, sy, sz = o[0] - ax, o[1] - ay, o[2] - az
    u = (sx * hx + sy * hy + sz * hz) / det
    if u < 0.0 or u > 1.0:
        return False
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) / det
    if v < 0.0 or u + v > 1.0:
        return False
    return (e2x * qx + e2y * qy + e2z * qz) / det > 0.0


@njit(cache=True)
def _entry(o: NDArray, d: NDArray, lo: NDArray, hi: NDArray) -> float:  # pragma: no cover
    """Ray parameter where the ray enters the box ``[lo, hi]`` (0 when it starts inside), -1 if it misses."""
    t0, t1 = 0.0, np.inf
    for k in range(3):
        if abs(d[k]) < 1e-300:
            if o[k] < lo[k] or o[k] > hi[k]:
                return -1.0
            continue
        a = (lo[k] - o[k]) / d[k]
        b = (hi[k] - o[k]) / d[k]
        t0 = max(t0, min(a, b))
        t1 = min(t1, max(a, b))
    return t0 if t0 <= t1 else -1.0


@njit(cache=True)
def _cast(
    origins: NDArray,
    directions: NDArray,
    triangles: NDArray,
    lo: NDArray,
    cell: float,
    shape: NDArray,
    start: NDArray,
    members: NDArray,
) -> NDArray:  # pragma: no cover
    """Any-hit query of each ray, walking the grid cells it crosses."""
    hi = lo + shape * cell
    hits = np.zeros(len(origins), dtype=np.bool_)
    idx = np.empty(3, dtype=np.int64)
    step = np.empty(3, dtype=np.int64)
    t_max = np.empty(3)
    t_delta = np.empty(3)
    for r in range(len(origins)):
        o, d = origins[r], directions[r]
        t = _entry(o, d, lo, hi)
        if t < 0.0:
            continue
        for k in range(3):
            p = o[k] + t * d[k]
            idx[k] = min(max(int((p - lo[k]) / cell), 0), shape[k] - 1)
            if d[k] > 0:
                step[k], t_max[k], t_delta[k] = 1, (lo[k] + (idx[k] + 1) * cell - o[k]) / d[k], cell / d[k]
            elif d[k] < 0:
                step[k], t_max[k], t_delta[k] = -1, (lo[k] + idx[k] * cell - o[k]) / d[k], -cell / d[k]
            else:
                step[k], t_max[k], t_delta[k] = 0, np.inf, np.inf
        while True:
            c = idx[0] + shape[0] * (idx[1] + shape[1] * idx[2])
            for m in range(start[c], start[c + 1]):
                if _hits_triangle(o, d, triangles[members[m]]):
                    hits[r] = True
                    break
            if hits[r]:
                break
            k = 0 if t_max[0] <= t_max[1] and t_max[0] <= t_max[2] else (1 if t_max[1] <= t_max[2] else 2)
            idx[k] += step[k]
            if idx[k] < 0 or idx[k] >= shape[k]:
                break
            t_max[k] += t_delta[k]
    return hits
