"""Resampling a mesh to a target node count: surface decimation, tetrahedralisation, shape distance.

- Surfaces are decimated by quadric edge collapse (fast-simplification, MIT;
  the vertices move to the quadric optimum, so the shape is kept closely).
- Volumes are made from the decimated boundary surface by TetGen (the
  ``tetgen`` wheel; TetGen itself is AGPL-3.0) with a radius-edge ratio of at
  most 1.5 and tetrahedra no larger than a regular one of the surface's mean
  edge. The surface node count is adjusted over a few runs until the whole
  mesh has the target count within :data:`NODE_TOLERANCE`; a decimated
  surface that intersects itself (thin walls at very few nodes) is retried
  with 30 % more surface nodes.
- :func:`hausdorff_distance` measures how far the shape moved.

Meshes with no more than ``(1 + NODE_TOLERANCE)`` times the target are not
decimated (refining adds no information). Node sets move with the surface:
each new surface node takes the sets of the nearest old surface node.
Both libraries are deterministic: the same mesh and target give the same
result, bit for bit.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import fast_simplification
import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import CellType, Mesh
from simgen.meshes.topology import boundary_faces, extract_surface, signed_volumes
from simgen.meshes.validate import validate_mesh

if TYPE_CHECKING:
    import tetgen

__all__ = ["NODE_TOLERANCE", "resample", "decimate_surface", "tetrahedralise", "hausdorff_distance"]

log = logging.getLogger("simgen.meshes")

#: Accepted relative difference between a resampled mesh's node count and the target.
NODE_TOLERANCE = 0.1
_TETGEN = {"minratio": 1.5, "mindihedral": 10.0, "quiet": True}
_TRIES = 6
#: Files TetGen writes into the working directory when the surface intersects itself.
_TETGEN_DEBRIS = ("_skipped.face", "_skipped.node")


def resample(mesh: Mesh, nodes: int, kind: CellType) -> Mesh:
    """``mesh`` as ``kind`` cells with about ``nodes`` nodes (see the module docstring).

    A tetrahedral mesh asked for as triangles becomes its boundary surface; a
    triangle surface asked for as tetrahedra must be closed. Node sets other
    than ``surface`` are transferred; the axis is kept.
    """
    if mesh.cell_type == kind and mesh.n_nodes <= nodes * (1 + NODE_TOLERANCE):
        return mesh
    surface = extract_surface(mesh)
    if kind == "triangle":
        if surface.n_nodes <= nodes * (1 + NODE_TOLERANCE):
            return surface
        points, cells = decimate_surface(surface.points, surface.cells, nodes)
    else:
        if mesh.cell_type == "triangle" and not trimesh.Trimesh(mesh.points, mesh.cells, process=False).is_watertight:
            raise MeshError(
                f"mesh {mesh.name!r}: an open triangle surface cannot be filled with tetrahedra; use triangles"
            )
        points, cells = tetrahedralise(surface.points, surface.cells, nodes, mesh.name)
    resampled = Mesh(points, cells, _transfer_sets(surface, points, cells), axis=mesh.axis, name=mesh.name)
    log.info(
        "mesh %r resampled: %d %s nodes -> %d %s nodes", mesh.name, mesh.n_nodes, mesh.cell_type, len(points), kind
    )
    try:
        return validate_mesh(resampled)
    except MeshError as exc:
        raise MeshError(f"resampling to {nodes} nodes failed: {exc}; try another node count") from None


def decimate_surface(
    points: NDArray[np.float64], tris: NDArray[np.integer], nodes: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A closed or open triangle surface decimated to about ``nodes`` nodes (quadric edge collapse)."""
    reduction = 1.0 - nodes / len(points)
    if reduction <= 0:
        return points, np.asarray(tris, dtype=np.int64)
    new_points, new_tris = fast_simplification.simplify(
        np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(tris, dtype=np.int64), reduction
    )
    return np.asarray(new_points, dtype=np.float64), np.asarray(new_tris, dtype=np.int64)


def tetrahedralise(
    points: NDArray[np.float64], tris: NDArray[np.integer], nodes: int, name: str = "mesh"
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Tetrahedra filling a closed outward surface, about ``nodes`` nodes in all (TetGen).

    TetGen comes with the optional ``tetra`` extra (its library is AGPL-3.0).
    """
    try:
        import tetgen
    except ImportError:
        raise MeshError(
            f"mesh {name!r}: filling a surface with tetrahedra needs the optional TetGen wrapper "
            "(pip install 'metapns[tetra]'; TetGen is AGPL-3.0), or use kind = 'triangle'"
        ) from None
    surface_nodes = min(len(points), max(nodes // 2, 50))
    best: tuple[float, NDArray[np.float64], NDArray[np.int64]] | None = None
    for _ in range(_TRIES):
        sp, st = decimate_surface(points, tris, surface_nodes)
        edge = trimesh.Trimesh(sp, st, process=False).edges_unique_length.mean()
        try:
            tet_points, tets, *_ = _tetrahedralize(tetgen.TetGen(sp, st.astype(np.int32)), edge**3 / (6 * np.sqrt(2)))
        except RuntimeError as exc:  # a coarse decimation can intersect itself: keep more surface nodes
            if surface_nodes == len(points):
                raise MeshError(f"mesh {name!r}: TetGen could not fill the surface ({exc})") from None
            surface_nodes = min(len(points), int(surface_nodes * 1.3))
            continue
        miss = abs(len(tet_points) / nodes - 1)
        if best is None or miss < best[0]:
            best = (miss, np.asarray(tet_points, dtype=np.float64), np.asarray(tets, dtype=np.int64))
        if miss <= NODE_TOLERANCE / 2 or (surface_nodes == len(points) and len(tet_points) < nodes):
            break
        surface_nodes = int(min(len(points), max(50, surface_nodes * (nodes / len(tet_points)) ** (2 / 3))))
    if best is None:
        raise MeshError(f"mesh {name!r}: TetGen could not fill the surface decimated to {surface_nodes} nodes")
    _, tet_points, tets = best
    negative = signed_volumes(tet_points, tets) < 0
    tets[negative] = tets[negative][:, [1, 0, 2, 3]]
    return tet_points, tets


def _tetrahedralize(tet: tetgen.TetGen, maxvolume: float) -> tuple:
    """``tet.tetrahedralize``, removing the files it leaves in the working directory when it fails."""
    before = {name for name in _TETGEN_DEBRIS if Path(name).exists()}
    try:
        return tet.tetrahedralize(maxvolume=maxvolume, **_TETGEN)
    finally:
        for name in set(_TETGEN_DEBRIS) - before:
            Path(name).unlink(missing_ok=True)


def hausdorff_distance(a: Mesh, b: Mesh, neighbours: int = 8) -> float:
    """Symmetric Hausdorff distance (mm) between the boundary surfaces of ``a`` and ``b``.

    Each node of one surface is measured against the triangles of the other
    around its ``neighbours`` nearest nodes (exact point-to-triangle
    distances); restricting the candidates can only overestimate, so this is
    an upper bound that is tight for surfaces of similar shape.
    """
    sa, sb = extract_surface(a), extract_surface(b)
    return max(_surface_distance(sa.points, sb), _surface_distance(sb.points, sa))


def _surface_distance(query: NDArray[np.float64], surface: Mesh, neighbours: int = 8) -> float:
    """Largest distance from ``query`` points to ``surface`` (an upper bound, see :func:`hausdorff_distance`)."""
    tris = surface.cells.astype(np.int64)
    k = min(neighbours, surface.n_nodes)
    _, near = cKDTree(surface.points).query(query, k=k)
    near = near.reshape(len(query), k)
    order = np.argsort(tris.ravel(), kind="stable")
    start = np.searchsorted(tris.ravel()[order], np.arange(surface.n_nodes + 1))
    worst = 0.0
    for chunk in np.array_split(np.arange(len(query)), max(1, len(query) // 4096)):
        vertex = near[chunk].ravel()
        count = start[vertex + 1] - start[vertex]
        offset = np.repeat(start[vertex] - np.cumsum(count) + count, count) + np.arange(count.sum())
        candidate = order[offset] // 3
        owner = np.repeat(np.repeat(chunk, k), count)
        closest = trimesh.triangles.closest_point(surface.points[tris[candidate]], query[owner])
        dist = np.linalg.norm(closest - query[owner], axis=1)
        best = np.full(len(query), np.inf)
        np.minimum.at(best, owner, dist)
        worst = max(worst, float(best[chunk].max()))
    return worst


def _transfer_sets(old: Mesh, points: NDArray[np.float64], cells: NDArray[np.int64]) -> dict[str, NDArray[np.int64]]:
    """The new mesh's ``surface`` and the sets of the surface ``old``, each new node taking its nearest old node's."""
    surface = np.unique(cells) if cells.shape[1] == 3 else np.unique(boundary_faces(cells))
    sets = {"surface": surface}
    names = [name for name in old.node_sets if name != "surface"]
    if not names:
        return sets
    _, nearest = cKDTree(old.points).query(points[surface])
    for name in names:
        member = np.zeros(old.n_nodes, dtype=bool)
        member[old.node_sets[name]] = True
        sets[name] = surface[member[nearest]]
    return sets
