"""Node sets and long axis of a ventricular mesh that carries none: epicardium, LV / RV endocardium, base.

The method works on the closed, outward-oriented boundary surface (a
tetrahedral mesh's boundary, or a closed triangle mesh) of one or two
ventricles whose cavities open at the base:

1. **Cavity or outside.** From each triangle a ray is cast along its outward
   normal. On the endocardium it crosses the cavity and hits the opposite
   wall; on the epicardium (and on the base cut) it escapes. A node is
   endocardial when most of its triangles' area is. Rays walk a grid of the
   triangles (:func:`simgen.meshes.rays.rays_hit`), so the surface is
   labelled at its own resolution: a decimated copy would close thin
   walls, such as the top of the septum, and join the two cavities.
2. **Cleaning.** Endocardial patches are split into connected pieces; the two
   largest holding at least :data:`MIN_CAVITY_SHARE` of the endocardial nodes
   are the cavities, smaller pieces (concave epicardium, e.g. the
   interventricular grooves, where rays hit the neighbouring wall) become
   epicardium.
3. **LV or RV.** With two cavities, the LV is the one whose nodes lie farther
   from the epicardium on average: the thick LV wall and the septum surround
   it, while the RV's thin free wall covers half of its crescent.
4. **Axis.** The long axis is the LV cavity's principal direction (largest
   variance of its nodes), pointing to its opening: the rim where the LV
   endocardium meets the rest of the surface. The base point is where the
   LV cavity ends on that line (98th percentile of its nodes' projections),
   the apex the lowest epicardial projection, and the reference direction (AHA angle 0) points from the
   axis to the RV cavity's centroid; an LV alone gets the x (or y) direction
   made orthogonal to the axis, as :func:`simgen.meshes.aha.estimate_axis`.
5. **Base.** Non-endocardial nodes in the basal half whose normal is within
   :data:`BASE_ANGLE` degrees of the axis direction (the flat or rounded cut
   and the valve rims), and those next to an endocardial node: on a closed
   surface the endocardium meets the rest only at the cavities' openings,
   whose rim nodes face half up, half into the cavity. Base nodes are
   neither epicardium nor endocardium, so the three sets are disjoint and
   cover the surface.

Limits: the cavities must open towards the base (a ray from a basal
endocardial triangle pointing out of the opening escapes and is taken for
epicardium, then re-joined to its cavity only if it touches it); the long
axis is the LV cavity's, so a very short, round LV gives an uncertain
direction; an LV alone has no anatomical angle 0. Meshes without a cavity
are refused. :func:`labelled_axis` gives the axis of step 4 for a mesh whose
node sets came from its file (:mod:`simgen.meshes.labels`); the agreement
of detection with such labels is measured in ``bench/labels.py``.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh
from simgen.meshes.rays import rays_hit
from simgen.meshes.topology import boundary_faces

__all__ = ["MIN_CAVITY_SHARE", "BASE_ANGLE", "detect_heart", "labelled_axis"]

#: Smallest share of the endocardial nodes a cavity holds.
MIN_CAVITY_SHARE = 0.05
#: Largest angle (degrees) between a base node's normal and the long axis.
BASE_ANGLE = 45.0


def detect_heart(mesh: Mesh) -> tuple[dict[str, NDArray[np.int64]], LongAxis]:
    """Detected node sets (mesh node ids) and long axis of a one- or two-ventricle mesh.

    Sets: ``epicardium``, ``endocardium``, ``base`` and, with two cavities,
    ``lv_endocardium`` and ``rv_endocardium`` (their union is
    ``endocardium``). See the module docstring for the method.
    """
    keep, surface = _surface(mesh)
    endo = _endocardial_nodes(surface)
    graph = _graph(surface, len(keep))
    cavities = _cavities(graph, endo, mesh.name)
    if len(cavities) == 2:
        epi_tree = cKDTree(surface.vertices[~endo])
        depth = [epi_tree.query(surface.vertices[c])[0].mean() for c in cavities]
        cavities = cavities if depth[0] >= depth[1] else cavities[::-1]
    endo = np.zeros(len(keep), dtype=bool)
    endo[np.concatenate(cavities)] = True
    axis = _axis(surface, graph, cavities, endo)
    height = (surface.vertices - axis.apex) @ axis.direction / axis.length
    base = _base_nodes(surface, graph, endo, axis.direction, height)
    sets = {"epicardium": ~endo & ~base, "endocardium": endo, "base": base}
    if len(cavities) == 2:
        for name, cavity in zip(("lv_endocardium", "rv_endocardium"), cavities):
            sets[name] = np.zeros(len(keep), dtype=bool)
            sets[name][cavity] = True
    return {name: keep[np.flatnonzero(member)] for name, member in sets.items()}, axis


def labelled_axis(mesh: Mesh) -> LongAxis:
    """The long axis (module docstring, step 4) of a mesh whose node sets a file gave.

    The LV cavity is ``lv_endocardium`` (with ``rv_endocardium`` giving angle
    0) or, for an LV alone, ``endocardium``; :class:`MeshError` if the mesh
    has neither or its cavity has no opening.
    """
    keep, surface = _surface(mesh)
    local = np.full(mesh.n_nodes, -1, dtype=np.int64)
    local[keep] = np.arange(len(keep))
    names = ["lv_endocardium", "rv_endocardium"] if "rv_endocardium" in mesh.node_sets else ["endocardium"]
    cavities = [local[mesh.nodes(name)] for name in names]
    cavities = [c[c >= 0] for c in cavities]
    if any(len(c) == 0 for c in cavities):
        raise MeshError(f"mesh {mesh.name!r}: node sets {names} hold no surface node")
    endo = np.zeros(len(keep), dtype=bool)
    endo[np.concatenate(cavities)] = True
    return _axis(surface, _graph(surface, len(keep)), cavities, endo)


def _surface(mesh: Mesh) -> tuple[NDArray[np.int64], trimesh.Trimesh]:
    """The mesh nodes on its boundary surface, and that surface on them (nodes numbered in that order)."""
    faces = boundary_faces(mesh.cells) if mesh.cell_type == "tetra" else mesh.cells
    keep = np.unique(faces)
    local = np.full(mesh.n_nodes, -1, dtype=np.int64)
    local[keep] = np.arange(len(keep))
    return keep, trimesh.Trimesh(mesh.points[keep], local[faces], process=False)


def _base_nodes(
    surface: trimesh.Trimesh,
    graph: coo_matrix,
    endo: NDArray[np.bool_],
    direction: NDArray[np.float64],
    height: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """Base nodes (module docstring, step 5): the basal cut facing along the axis, and the cavities' rims."""
    facing = surface.vertex_normals @ direction > np.cos(np.radians(BASE_ANGLE))
    rim = ~endo & (graph @ endo.astype(np.int64) + graph.T @ endo.astype(np.int64) > 0)
    return ~endo & (facing | rim) & (height > 0.5)


def _endocardial_nodes(surface: trimesh.Trimesh) -> NDArray[np.bool_]:
    """Nodes most of whose incident area faces a cavity (their normal rays hit the surface)."""
    normals = surface.face_normals
    edge = surface.edges_unique_length.mean()
    hits = rays_hit(surface.triangles_center + 1e-3 * edge * normals, normals, surface.triangles)
    weight = np.zeros(len(surface.vertices))
    total = np.zeros(len(surface.vertices))
    for corner in surface.faces.T:
        np.add.at(weight, corner, surface.area_faces * hits)
        np.add.at(total, corner, surface.area_faces)
    return weight > 0.5 * total


def _graph(surface: trimesh.Trimesh, n: int) -> coo_matrix:
    edges = surface.edges_unique
    return coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()


def _pieces(graph: coo_matrix, member: NDArray[np.bool_]) -> list[NDArray[np.int64]]:
    """Connected pieces of the nodes ``member``, largest first."""
    idx = np.flatnonzero(member)
    _, label = connected_components(graph[idx][:, idx], directed=False)
    pieces = [idx[label == k] for k in range(label.max() + 1)] if len(idx) else []
    return sorted(pieces, key=len, reverse=True)


def _cavities(graph: coo_matrix, endo: NDArray[np.bool_], name: str) -> list[NDArray[np.int64]]:
    """The one or two endocardial pieces large enough to be cavities, largest first."""
    pieces = _pieces(graph, endo)
    cavities = [p for p in pieces[:2] if len(p) >= MIN_CAVITY_SHARE * endo.sum()]
    if not cavities:
        raise MeshError(
            f"mesh {name!r}: no ventricular cavity found (no surface faces an enclosed cavity); "
            "give its node sets in the file or the spec (node_set_arrays)"
        )
    return cavities


def _axis(
    surface: trimesh.Trimesh, graph: coo_matrix, cavities: list[NDArray[np.int64]], endo: NDArray[np.bool_]
) -> LongAxis:
    """Long axis from the LV cavity (see the module docstring, step 4)."""
    points = surface.vertices
    lv = points[cavities[0]]
    centre = lv.mean(axis=0)
    _, vecs = np.linalg.eigh((lv - centre).T @ (lv - centre))
    d = vecs[:, -1]
    in_lv = np.zeros(len(points), dtype=bool)
    in_lv[cavities[0]] = True
    rows, cols = graph.nonzero()
    rim = np.unique(np.concatenate([rows[in_lv[rows] & ~in_lv[cols]], cols[in_lv[cols] & ~in_lv[rows]]]))
    if len(rim) == 0:
        raise MeshError("the LV cavity has no opening: the surface is not a ventricle open at its base")
    if (points[rim].mean(axis=0) - centre) @ d < 0:
        d = -d
    base_height = float(np.percentile((lv - centre) @ d, 98))
    apex_height = float(((points[~endo] - centre) @ d).min())
    if len(cavities) == 2:
        towards = points[cavities[1]].mean(axis=0) - centre
    else:
        towards = np.eye(3)[0 if abs(d[0]) < np.sqrt(0.5) else 1]
    reference = towards - (towards @ d) * d
    return LongAxis(
        apex=centre + apex_height * d, base=centre + base_height * d, reference=reference / np.linalg.norm(reference)
    )
