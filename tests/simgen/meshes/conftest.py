"""Hard surfaces for the resampling tests: a dense BiV and a BiV merged from three separately meshed parts."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

from shared.mesh import Mesh
from simgen.meshes import biv_ellipsoid


def dense_biv(nodes: int = 29_000) -> Mesh:
    """A procedural BiV closed surface of about ``nodes`` nodes."""
    return biv_ellipsoid(nodes, "triangle", name="dense-biv")


def _centroid_split(points: list, tris: np.ndarray) -> np.ndarray:
    """Each triangle split into three at its centroid (``points`` grows); the edges, so the seams, are kept."""
    out = []
    for a, b, c in tris:
        points.append((points[a] + points[b] + points[c]) / 3)
        m = len(points) - 1
        out += [(a, b, m), (b, c, m), (c, a, m)]
    return np.array(out, dtype=np.int64)


def merged_parts(path: Path, nodes: int = 3000) -> Path:
    """A BiV surface saved as three separately meshed parts, welded at the seams, as a ``.vtk`` file.

    The LV-facing, RV-facing and remaining triangles are meshed at three
    resolutions (kept; centroid-split once, with needle triangles; twice),
    the second part is wound inwards, and 40 seam edges are split 2 % from an
    end, leaving a sliver triangle on each side. The parts' nodes are
    duplicated and then welded, as an export of three parts merges them.
    """
    base = biv_ellipsoid(nodes, "triangle")
    tris = base.cells.astype(np.int64)
    part = np.zeros(len(tris), dtype=np.int64)
    part[np.isin(tris, base.nodes("lv_endocardium")).all(axis=1)] = 1
    part[np.isin(tris, base.nodes("rv_endocardium")).all(axis=1)] = 2
    points = list(base.points)
    pieces = [tris[part == 0], _centroid_split(points, tris[part == 1])]
    pieces.append(_centroid_split(points, _centroid_split(points, tris[part == 2])))
    pieces[1] = pieces[1][:, ::-1]
    tris, owner = np.concatenate(pieces), np.repeat([0, 1, 2], [len(p) for p in pieces])
    tris = _seam_slivers(points, tris, owner, 40)
    points = np.asarray(points)
    # separate node copies per part, then welded by coordinates
    copies = points[tris].reshape(-1, 3)
    welded, index = np.unique(np.round(copies, 9), axis=0, return_inverse=True)
    meshio.write(path, meshio.Mesh(welded, [("triangle", index.reshape(-1, 3))]))
    return path


def _seam_slivers(points: list, tris: np.ndarray, owner: np.ndarray, count: int) -> np.ndarray:
    """``tris`` with ``count`` seam edges (between parts) split 2 % from one end, each neighbour into two."""
    half = tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    key = {tuple(h): i for i, h in enumerate(half.tolist())}
    used: set[int] = set()
    out = tris.tolist()
    added = 0
    for i, (a, b) in enumerate(half.tolist()):
        j = key.get((b, a))
        t, u = i // 3, (j // 3 if j is not None else -1)
        if j is None or owner[t] == owner[u] or t in used or u in used:
            continue
        used |= {t, u}
        points.append(0.98 * points[a] + 0.02 * points[b])
        m = len(points) - 1
        for tri, (p, q) in ((t, (a, b)), (u, (b, a))):
            r = next(v for v in tris[tri] if v not in (p, q))
            out[tri] = [p, m, r]
            out.append([m, q, r])
        added += 1
        if added == count:
            break
    return np.array(out, dtype=np.int64)


@pytest.fixture(scope="session")
def merged_file(tmp_path_factory) -> Path:
    return merged_parts(tmp_path_factory.mktemp("merged") / "merged-biv.vtk")
