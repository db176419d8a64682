"""Safe repairs of mesh files, each reported: hexahedra split, unused nodes dropped, degenerate cells removed,
triangle orientation made consistent and outward.

Every repair that changes the mesh logs a warning on the ``simgen.meshes``
logger naming the file and what changed (for dropped nodes, the renumbering);
a mesh that needs none comes back unchanged, array for array. Repairs that
would guess (inverted tetrahedra, non-manifold or disconnected meshes) are not
made: :func:`~simgen.meshes.validate.validate_mesh` refuses those meshes.
"""

from __future__ import annotations

import functools
import itertools
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

# Hexahedron in VTK order: bottom 0-3, top 4-7, corner i of the unit cube at _CUBE[i].
_CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
# Its sides, each a cycle of corners with diagonals (q0, q2) and (q1, q3).
_SIDES = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
# Dompierre et al. (1999), "How to subdivide pyramids, prisms and hexahedra into tetrahedra": with corner 0
# the smallest node, the sides at corner 0 are cut through it; n of the three sides at corner 6 are cut
# through corner 6. Up to a rotation about the diagonal 0-6, one split per n:
_DOMPIERRE = [
    # n = 0: sides cut along 0-2, 0-5, 0-7, 2-5, 2-7, 5-7; four corner tetrahedra and a central one.
    (
        [[0, 2], [0, 5], [0, 7], [2, 5], [2, 7], [5, 7]],
        [[1, 0, 2, 5], [3, 0, 7, 2], [4, 0, 5, 7], [6, 2, 7, 5], [0, 2, 5, 7]],
    ),
    # n = 1 (4-6), n = 2 (4-6, 1-6): two prisms either side of the plane 0-2-6-4, cut along 0-6.
    (
        [[0, 2], [0, 5], [0, 7], [4, 6], [2, 5], [2, 7]],
        [[0, 1, 2, 5], [0, 2, 6, 5], [0, 6, 4, 5], [0, 2, 3, 7], [0, 2, 6, 7], [0, 6, 4, 7]],
    ),
    (
        [[0, 2], [0, 5], [0, 7], [4, 6], [1, 6], [2, 7]],
        [[0, 4, 5, 6], [0, 1, 2, 6], [0, 1, 6, 5], [0, 2, 3, 7], [0, 2, 6, 7], [0, 6, 4, 7]],
    ),
    # n = 3: sides cut along 0-2, 0-5, 0-7, 4-6, 1-6, 3-6; six tetrahedra around the diagonal 0-6 (Kuhn).
    (
        [[0, 2], [0, 5], [0, 7], [4, 6], [1, 6], [3, 6]],
        [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]],
    ),
]
_SHOW = 10  # indices quoted per message


def _cube_symmetries() -> list[NDArray[np.int64]]:
    """The 48 rotations and reflections of the cube as corner maps: corner i goes to corner ``map[i]``."""
    maps = []
    for axes in itertools.permutations(range(3)):
        for flip in itertools.product((0, 1), repeat=3):
            moved = np.abs(_CUBE[:, axes] - np.array(flip))
            maps.append(np.flatnonzero((moved[:, None] == _CUBE[None]).all(axis=2)) % 8)
    return maps


@functools.cache
def _hexahedron_splits() -> dict[int, NDArray[np.int64]]:
    """Tetrahedra (local corners, positively oriented on the unit cube) for each way the six sides are cut.

    Key: bit ``s`` set when side ``s`` is cut along ``(q1, q3)`` rather than ``(q0, q2)``. Holds every
    cut a node numbering makes (some corner, the smallest node, is cut through on its three sides): 42 of
    the 64.
    """
    splits = {}
    for key in range(64):
        cut = {frozenset(side[[0, 2]] if not key >> s & 1 else side[[1, 3]]) for s, side in enumerate(_SIDES)}
        for corner_map in _cube_symmetries():
            moved = {frozenset(corner_map[list(edge)]) for edge in cut}
            for diagonals, tets in _DOMPIERRE:
                if moved == {frozenset(edge) for edge in diagonals}:
                    back = np.argsort(corner_map)[np.array(tets)]  # back to this hexahedron's corners
                    negative = signed_volumes(_CUBE.astype(np.float64), back) < 0
                    back[negative] = back[negative][:, [1, 0, 2, 3]]
                    splits[key] = back
                    break
            if key in splits:
                break
    return splits


def split_hexahedra(points: NDArray[np.float64], hexes: NDArray[np.integer], where: str) -> NDArray[np.int64]:
    """Five or six positively oriented tetrahedra per hexahedron (VTK corner order), conforming in any node order.

    Each quadrilateral side is cut along its diagonal through its smallest
    node number, so two hexahedra sharing a side cut it alike whatever their
    local corner orders; each hexahedron is then split into the tetrahedra
    consistent with its six cuts (Dompierre et al. 1999), without new nodes.
    Tetrahedra of a hexahedron come in its order; those with negative volume
    (mirrored corner orders) are listed in reverse orientation.
    """
    hexes = np.asarray(hexes, dtype=np.int64)
    # Corners ranked by node number (a repeated node, in a collapsed hexahedron, by corner), then each side's
    # cut: bit s of the key set when side s is cut along (q1, q3), through its smallest corner.
    rank = np.argsort(np.argsort(hexes, axis=1, kind="stable"), axis=1)
    key = ((rank[:, _SIDES].argmin(axis=2) % 2) << np.arange(len(_SIDES))).sum(axis=1)
    splits = _hexahedron_splits()
    parts, owner = [np.empty((0, 4), dtype=np.int64)], [np.empty(0, dtype=np.int64)]
    for k in np.unique(key):
        group = np.flatnonzero(key == k)
        parts.append(hexes[group][:, splits[k]].reshape(-1, 4))
        owner.append(group.repeat(len(splits[k])))
    tets = np.concatenate(parts)[np.argsort(np.concatenate(owner), kind="stable")]
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
