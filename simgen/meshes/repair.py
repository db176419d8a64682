"""Safe repairs of mesh files, each reported: hexahedra split, unused nodes dropped, degenerate cells removed,
triangle orientation made consistent and outward.

Every repair that changes the mesh logs a warning on the ``simgen.meshes``
logger naming the file and what changed (for dropped nodes, the renumbering);
a mesh that needs none comes back unchanged, array for array. Repairs that
would guess (inverted tetrahedra, non-manifold or disconnected meshes) are not
made: :func:`~simgen.meshes.validate.validate_mesh` refuses those meshes.
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from simgen.meshes.topology import group_rows, signed_volumes
from simgen.meshes.validate import degenerate_cells

__all__ = ["split_hexahedra", "drop_unused_nodes", "remove_degenerate_cells", "orient_triangles"]

log = logging.getLogger("simgen.meshes")

# Six tetrahedra around the diagonal 0-6 of a hexahedron in VTK order (bottom 0-3, top 4-7).
# Neighbouring hexahedra with the same local node order (structured grids, extruded meshes)
# cut their shared face along the same diagonal, so the split is conforming.
_KUHN = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])
_SHOW = 10  # indices quoted per message


def split_hexahedra(points: NDArray[np.float64], hexes: NDArray[np.integer], where: str) -> NDArray[np.int64]:
    """Six positively oriented tetrahedra per hexahedron (Kuhn split around the diagonal 0-6).

    Conforming when neighbouring hexahedra share their local node order; when
    they do not, the split leaves faces that :func:`validate_mesh` reports as
    non-manifold, and the mesh is refused there.
    """
    tets = np.asarray(hexes, dtype=np.int64)[:, _KUHN].reshape(-1, 4)
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [1, 0, 2, 3]]
    log.warning("%s: split %d hexahedra into %d tetrahedra", where, len(hexes), len(tets))
    return tets


def drop_unused_nodes(
    points: NDArray[np.float64], cells: NDArray[np.integer], where: str
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """``(points, cells, kept)`` without the nodes in no cell; ``kept[new] = old`` index.

    When nodes are dropped, a warning lists them and the renumbering of the others.
    """
    cells = np.asarray(cells, dtype=np.int64)
    kept = np.unique(cells)
    if len(kept) == len(points):
        return points, cells, kept
    new_index = np.full(len(points), -1, dtype=np.int64)
    new_index[kept] = np.arange(len(kept))
    dropped = np.flatnonzero(new_index < 0)
    moved = np.flatnonzero(kept != np.arange(len(kept)))
    pairs = ", ".join(f"{kept[i]}->{i}" for i in moved[:_SHOW])
    log.warning(
        "%s: dropped %d unused node(s) (in no cell) %s%s; the other nodes are renumbered old->new: %s%s",
        where,
        len(dropped),
        dropped[:_SHOW].tolist(),
        " ..." if len(dropped) > _SHOW else "",
        pairs or "none moves",
        f" ... ({len(moved)} moved; node i becomes i minus the dropped nodes before it)" if len(moved) > _SHOW else "",
    )
    return points[kept], new_index[cells], kept


def remove_degenerate_cells(points: NDArray[np.float64], cells: NDArray[np.int64], where: str) -> NDArray[np.int64]:
    """``cells`` without zero-area triangles or zero-volume tetrahedra, with a warning naming them."""
    bad = degenerate_cells(points, cells)
    if len(bad) == 0:
        return cells
    what = "zero-area triangle" if cells.shape[1] == 3 else "zero-volume tetrahedra"
    log.warning("%s: removed %d degenerate cell(s) (%s) %s", where, len(bad), what, bad[:_SHOW].tolist())
    return np.delete(cells, bad, axis=0)


def orient_triangles(points: NDArray[np.float64], tris: NDArray[np.int64], where: str) -> NDArray[np.int64]:
    """Triangles wound consistently within each connected piece, normals pointing outward.

    Outward: the piece's signed volume about its own centroid is positive
    (exact for closed surfaces, the majority direction for open ones). A mesh
    already consistent and outward is returned as it is.
    """
    tris = np.asarray(tris, dtype=np.int64)
    directed = tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    _, counts = group_rows(directed)
    if (counts > 1).any():
        surface = trimesh.Trimesh(points, tris.copy(), process=False)
        trimesh.repair.fix_winding(surface)
        fixed = np.asarray(surface.faces, dtype=np.int64)
        log.warning(
            "%s: made the winding of %d triangle(s) consistent with their neighbours",
            where,
            int((fixed != tris).any(axis=1).sum()),
        )
        tris = fixed
    n = len(points)
    graph = coo_matrix((np.ones(2 * len(tris)), (np.repeat(tris[:, 0], 2), tris[:, 1:].ravel())), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    piece = label[tris[:, 0]]
    p = points[tris]
    centre = np.array([points[label == k].mean(axis=0) for k in range(label.max() + 1)])[piece]
    a, b, c = p[:, 0] - centre, p[:, 1] - centre, p[:, 2] - centre
    volume = np.bincount(piece, np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=label.max() + 1)
    inward = np.flatnonzero(volume < 0)
    if len(inward):
        flip = np.isin(piece, inward)
        tris = tris.copy()
        tris[flip] = tris[flip][:, ::-1]
        log.warning("%s: flipped %d inward-facing triangle(s) to point outward", where, int(flip.sum()))
    return tris
