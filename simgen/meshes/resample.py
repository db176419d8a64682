"""Resampling a mesh to a target node count: isotropic surface remeshing, tetrahedralisation, shape distance.

- Surfaces are remeshed isotropically (:mod:`simgen.meshes.remesh`): every
  edge close to a length ``L``, the nodes on the original surface, no needle
  or cap triangle. ``L`` starts from the surface area (an equilateral
  triangulation with the target node count) and is corrected from the node
  count over up to :data:`_TRIES` remeshings, until the count is within
  ``NODE_TOLERANCE / 2`` of the target (the closest try is kept). Dense
  surfaces are first decimated to twice the target by quadric edge
  collapse (fast-simplification, MIT), which keeps the shape closely.
- Volumes are filled by one of :data:`~simgen.meshes.fillers.FILLERS`
  (:mod:`simgen.meshes.fillers`; ``auto``: TetGen where it is installed and
  the surface does not cross itself, else fTetWild). TetGen fills the
  surface remeshed at ``L``, kept as it is (no nodes inserted on it), with
  tetrahedra no larger than a regular one of edge ``L`` and radius-edge
  ratio at most 1.5, then optimised by flips and smoothing towards dihedral
  angles between 15 and 160 degrees (a bound TetGen tries to meet, not a
  guarantee); a remeshed surface that crosses itself, at a thin wall, is
  remeshed 15 % finer before TetGen sees it; where the count then misses the
  target, the surface alone is remeshed finer, 5 % at a time, and the
  interior keeps the coarser length. fTetWild fills the decimated surface
  at ideal edge ``L`` and makes its own surface. Either way ``L`` is
  corrected from the total node count as for surfaces. Slivers lying flat
  against the surface (two faces on it, a dihedral angle below
  :data:`PEEL_ANGLE`) are removed, which flips the surface diagonal under
  them.
- :func:`hausdorff_distance` measures how far the shape moved.

A mesh already of the asked cell type, within :data:`NODE_TOLERANCE` of the
target and with no angle below :data:`KEEP_ANGLE` is kept as it is; any
other is remeshed, coarser or finer. Node sets move with the surface: each
new surface node takes the sets of the nearest old surface node. The
remeshing and both libraries are deterministic: the same mesh and target
give the same result, bit for bit.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import fast_simplification
import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import CellType, Mesh
from simgen.meshes.fillers import fill, resolve_filler
from simgen.meshes.quality import cell_angles
from simgen.meshes.remesh import closest_points, crossing_edges, edge_length_for, remesh
from simgen.meshes.topology import boundary_faces, extract_surface, group_rows, signed_volumes, tet_faces
from simgen.meshes.validate import mesh_problems, non_manifold_nodes, validate_mesh

__all__ = [
    "NODE_TOLERANCE",
    "KEEP_ANGLE",
    "PEEL_ANGLE",
    "resample",
    "remesh_surface",
    "decimate_surface",
    "tetrahedralise",
    "hausdorff_distance",
]

log = logging.getLogger("simgen.meshes")

#: Accepted relative difference between a resampled mesh's node count and the target.
NODE_TOLERANCE = 0.1
#: Smallest angle (degrees) of a mesh kept without remeshing: triangle angle, tetrahedron dihedral angle.
KEEP_ANGLE = {"triangle": 20.0, "tetra": 10.0}
_TRIES = 4
#: A remeshed surface that crosses itself is filled with edges this much shorter, up to _TRIES times; where
#: the count then misses the target, its surface alone is remeshed, _UNCROSS_STEP shorter up to _UNCROSS_TRIES times.
_REFINE_STEP = 0.85
_UNCROSS_STEP, _UNCROSS_TRIES = 0.95, 8
#: Remeshed surfaces keep about 30 % more nodes than an equilateral one of edge ``L``: ``L`` starts longer.
_LENGTH_FACTOR = 1.1
#: Interior volume per node (in units of ``L^3``) of a TetGen fill, for the first guess of ``L``.
_VOLUME_PER_NODE = 0.2
#: Tetrahedra with two faces on the surface and a dihedral angle below this (degrees) are removed.
PEEL_ANGLE = 10.0


def resample(mesh: Mesh, nodes: int, kind: CellType, filler: str | None = None) -> Mesh:
    """``mesh`` as ``kind`` cells with about ``nodes`` nodes (see the module docstring).

    A tetrahedral mesh asked for as triangles becomes its boundary surface; a
    triangle surface asked for as tetrahedra must be closed. Node sets other
    than ``surface`` are transferred; the axis is kept. ``filler``: one of
    :data:`~simgen.meshes.fillers.FILLERS` (``None``: ``"auto"``).
    """
    if mesh.cell_type == kind and _keep(mesh, nodes):
        return mesh
    surface = extract_surface(mesh)
    if kind == "triangle":
        if _keep(surface, nodes):
            return surface
        points, cells = remesh_surface(surface.points, surface.cells, nodes)
    else:
        if mesh.cell_type == "triangle" and not trimesh.Trimesh(mesh.points, mesh.cells, process=False).is_watertight:
            raise MeshError(
                f"mesh {mesh.name!r}: an open triangle surface cannot be filled with tetrahedra; use triangles"
            )
        points, cells = tetrahedralise(surface.points, surface.cells, nodes, mesh.name, filler)
    resampled = Mesh(points, cells, _transfer_sets(surface, points, cells), axis=mesh.axis, name=mesh.name)
    log.info(
        "mesh %r resampled: %d %s nodes -> %d %s nodes", mesh.name, mesh.n_nodes, mesh.cell_type, len(points), kind
    )
    try:
        return validate_mesh(resampled)
    except MeshError as exc:
        raise MeshError(f"resampling to {nodes} nodes failed: {exc}; try another node count") from None


def _keep(mesh: Mesh, nodes: int) -> bool:
    """Whether ``mesh`` is within the node tolerance of ``nodes`` and has no angle below :data:`KEEP_ANGLE`."""
    if abs(mesh.n_nodes / nodes - 1) > NODE_TOLERANCE:
        return False
    return float(cell_angles(mesh.points, mesh.cells).min()) >= KEEP_ANGLE[mesh.cell_type]


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


def remesh_surface(
    points: NDArray[np.float64], tris: NDArray[np.integer], nodes: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A closed or open triangle surface remeshed isotropically to about ``nodes`` nodes.

    Dense surfaces are first decimated to ``2 nodes``; each remeshing starts
    from there, the edge length corrected from the node count over up to
    :data:`_TRIES` remeshings.
    """
    area = float(trimesh.Trimesh(points, tris, process=False).area)
    length = _LENGTH_FACTOR * edge_length_for(area, nodes)

    start = decimate_surface(points, tris, 2 * nodes)

    def make(length: float) -> tuple:
        return length, remesh(*start, length, reference=(points, tris))

    return _fit_length(length, nodes, make)


def tetrahedralise(
    points: NDArray[np.float64], tris: NDArray[np.integer], nodes: int, name: str = "mesh", filler: str | None = None
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Tetrahedra filling a closed outward surface, about ``nodes`` nodes in all.

    ``filler`` (:func:`~simgen.meshes.fillers.resolve_filler`; ``None``:
    ``"auto"``): TetGen gets the surface remeshed with edges of length ``L``
    and keeps it as it is (its ``-Y``), adding interior nodes until no
    tetrahedron is larger than a regular one of edge ``L`` and the quality
    bounds hold; fTetWild gets the decimated surface and ideal edge ``L``.
    ``L`` is corrected from the node count over up to :data:`_TRIES` fills.
    With ``auto``, a surface TetGen refuses (a crossing the check missed) is
    filled by fTetWild. fTetWild's volume keeps its largest piece (connected
    through faces) and must be a valid closed volume (:func:`_closed_volume`).
    """
    requested, filler = filler or "auto", resolve_filler(filler, points, tris, name)
    solid = trimesh.Trimesh(points, tris, process=False)
    area, volume = float(solid.area), abs(float(solid.volume))
    # nodes ~ surface nodes 2 A / (sqrt(3) L^2) + interior nodes V / (c L^3): solve for L by bisection
    lo, hi = 1e-3 * np.cbrt(volume), 10 * np.cbrt(volume)
    for _ in range(60):
        length = np.sqrt(lo * hi)
        estimate = 2 * area / (np.sqrt(3) * length**2) + volume / (_VOLUME_PER_NODE * length**3)
        lo, hi = (length, hi) if estimate > nodes else (lo, length)
    start = decimate_surface(points, tris, 2 * nodes)
    if filler == "tetgen":
        try:
            return _tetgen_fit(points, tris, start, length, nodes, name)
        except MeshError as exc:
            if requested != "auto":
                raise
            log.warning("mesh %r: %s; filling it with fTetWild instead", name, exc)

    def fill_ftetwild(length: float) -> tuple:
        return length, _manifold(*_largest_piece(*fill("ftetwild", *start, length, name)))

    return _closed_volume(*_oriented(*_fit_length(length, nodes, fill_ftetwild)), name)


def _tetgen_fit(
    points: NDArray[np.float64],
    tris: NDArray[np.integer],
    start: tuple[NDArray[np.float64], NDArray[np.int64]],
    length: float,
    nodes: int,
    name: str,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """TetGen's fill of the surface ``(points, tris)`` remeshed from ``start`` at about ``nodes`` nodes
    (:func:`tetrahedralise`), starting from edge ``length``."""

    def fill_tetgen(length: float, surface_only: bool = False) -> tuple:
        """Tetrahedra of edge ``length``; a remeshed surface that crosses itself (a thin wall at a coarse
        ``length``) is remeshed finer, with the interior (``surface_only``) or without it."""
        step, tries = (_UNCROSS_STEP, _UNCROSS_TRIES) if surface_only else (_REFINE_STEP, _TRIES)
        surface_length = length
        sp, st = remesh(*start, length, reference=(points, tris))
        for _ in range(tries):
            if not crossing_edges(sp, st):
                break
            surface_length *= step
            sp, st = remesh(*start, surface_length, reference=(points, tris))
        interior = length if surface_only else surface_length
        return interior, fill("tetgen", sp, st, interior, name)

    tet_points, tets = _fit_length(length, nodes, fill_tetgen)
    if abs(len(tet_points) / nodes - 1) > NODE_TOLERANCE:  # thin walls refined everywhere: refine the surface alone
        tet_points, tets = min(
            ((tet_points, tets), _fit_length(length, nodes, lambda length: fill_tetgen(length, surface_only=True))),
            key=lambda mesh: abs(len(mesh[0]) / nodes - 1),
        )
    return _oriented(tet_points, tets)


def _largest_piece(points: NDArray[np.float64], tets: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray]:
    """The tetrahedra of the largest piece connected through shared faces (fTetWild may leave specks, or
    pieces that touch only at an edge or a node), and only the nodes they use."""
    tets = np.asarray(tets, np.int64)
    faces = np.sort(tet_faces(tets), axis=1)
    inverse, counts = group_rows(faces)
    owner = np.repeat(np.arange(len(tets)), 4)
    order = np.argsort(inverse, kind="stable")
    pairs = owner[order].reshape(-1)
    inner = counts[inverse[order]] == 2
    first, second = pairs[inner][0::2], pairs[inner][1::2]
    graph = coo_matrix((np.ones(len(first)), (first, second)), shape=(len(tets),) * 2)
    _, piece = connected_components(graph, directed=False)
    kept = tets[piece == np.bincount(piece).argmax()]
    used, renumbered = np.unique(kept, return_inverse=True)
    if len(kept) < len(tets):
        log.info("fTetWild: kept the largest of %d pieces (%d of %d tetrahedra)", piece.max() + 1, len(kept), len(tets))
    return points[used], renumbered.reshape(-1, 4)


def _manifold(points: NDArray[np.float64], tets: NDArray[np.int64], rounds: int = 5) -> tuple[NDArray, NDArray]:
    """``(points, tets)`` without pinches: at each node where the boundary is not a manifold (two parts of the
    volume meeting at a node or an edge), the tetrahedra around it that are not face-connected to its largest
    fan are dropped (all of them, a dent in the surface, when they are one fan and the boundary is pinched
    there all the same), then specks and unused nodes (:func:`_largest_piece`); up to ``rounds`` times."""
    for _ in range(rounds):
        bad = non_manifold_nodes(tets)
        if not len(bad):
            break
        drop = np.zeros(len(tets), bool)
        for node in bad:
            around = np.flatnonzero((tets == node).any(axis=1))
            faces = np.sort(tet_faces(tets[around]), axis=1)
            with_node = (faces == node).any(axis=1)  # the faces through the node link the fan
            inverse, counts = group_rows(faces)
            owner = np.repeat(np.arange(len(around)), 4)
            shared = with_node & (counts[inverse] == 2)
            order = np.argsort(inverse[shared], kind="stable")
            pairs = owner[shared][order].reshape(-1, 2)
            graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(around),) * 2)
            count, fan = connected_components(graph, directed=False)
            # several fans: keep the largest; one fan whose boundary is pinched anyway: the node's star goes (a dent)
            drop[around if count == 1 else around[fan != np.bincount(fan).argmax()]] = True
        if not drop.any():
            break
        log.info("fTetWild: dropped %d tetrahedra pinching the boundary at %d node(s)", int(drop.sum()), len(bad))
        points, tets = _largest_piece(points, tets[~drop])
    return points, tets


def _closed_volume(points: NDArray[np.float64], tets: NDArray[np.int64], name: str) -> tuple[NDArray, NDArray]:
    """``(points, tets)`` if they are a valid closed volume (:func:`~simgen.meshes.validate.mesh_problems`), else
    :class:`MeshError` saying what is wrong."""
    problems = mesh_problems(Mesh(points, tets))
    if problems:
        raise MeshError(
            f"mesh {name!r}: fTetWild's volume is not a valid closed volume ({'; '.join(problems[:3])}); "
            "fill at another --nodes, or repair the surface first"
        )
    return points, tets


def _oriented(points: NDArray[np.float64], tets: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Tetrahedra turned to positive volume, without the slivers lying flat on the surface (:func:`_peel`)."""
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [1, 0, 2, 3]]
    for _ in range(3):  # peeling one can lay the next flat on the surface
        tets = _peel(points, tets)
    return points, tets


def _peel(points: NDArray[np.float64], tets: NDArray[np.int64]) -> NDArray[np.int64]:
    """``tets`` without the slivers that lie flat against the surface (two boundary faces, a dihedral
    angle below :data:`PEEL_ANGLE`): removing one flips the surface diagonal under it.

    Kept as they are when the peeled mesh would not be valid (a surface edge
    already there, a node left out).
    """
    faces = np.sort(tet_faces(tets), axis=1)
    inverse, counts = group_rows(faces)
    outer = (counts[inverse] == 1).reshape(-1, 4).sum(axis=1)
    flat = (outer == 2) & (cell_angles(points, tets).min(axis=1) < PEEL_ANGLE)
    if not flat.any():
        return tets
    peeled = tets[~flat]
    if len(np.unique(peeled)) < len(points) or mesh_problems(Mesh(points, peeled)):
        return tets
    log.info("removed %d flat tetrahedra lying on the surface", int(flat.sum()))
    return peeled


def _fit_length(length: float, nodes: int, make: Callable[[float], tuple]) -> tuple:
    """The mesh of ``make(length)`` closest to ``nodes`` nodes over up to :data:`_TRIES` lengths.

    ``make`` returns ``(length it used, (points, cells))``. The length
    follows a secant on ``log nodes`` against ``log length`` (slope -2 to
    begin with) until the count is within ``NODE_TOLERANCE / 2``.
    """
    tried: list[tuple[float, float]] = []
    best: tuple[float, tuple] | None = None
    for _ in range(_TRIES):
        used, mesh = make(length)
        count = len(mesh[0])
        miss = abs(count / nodes - 1)
        if best is None or miss < best[0]:
            best = (miss, mesh)
        if miss <= NODE_TOLERANCE / 2:
            break
        tried.append((np.log(used), np.log(count)))
        slope = -2.0
        if len(tried) >= 2 and tried[-1][0] != tried[-2][0]:
            slope = float(np.clip((tried[-1][1] - tried[-2][1]) / (tried[-1][0] - tried[-2][0]), -4.0, -1.0))
        length = float(np.exp(tried[-1][0] + (np.log(nodes) - tried[-1][1]) / slope))
    assert best is not None
    return best[1]


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
    return float(closest_points(query, surface.points, surface.cells, neighbours)[1].max())


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
