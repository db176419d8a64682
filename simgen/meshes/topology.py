"""Mesh topology helpers: the edge graph, signed volumes, surface extraction (and, from :mod:`shared.topology`,
row grouping and boundary faces)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from shared.graph import edge_length_graph
from shared.mesh import Mesh
from shared.topology import boundary_faces, group_rows, tet_faces

__all__ = ["edge_graph", "tet_faces", "group_rows", "boundary_faces", "extract_surface", "signed_volumes"]


def edge_graph(mesh: Mesh) -> sp.csr_matrix:
    """Symmetric sparse graph of the mesh edges weighted by their length (mm), for geodesic distances."""
    return edge_length_graph(mesh.points, mesh.edges())


def signed_volumes(points: NDArray[np.float64], tets: NDArray[np.integer]) -> NDArray[np.float64]:
    """Signed volume of each tetrahedron (positive for right-handed ordering)."""
    p = points[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6


def extract_surface(mesh: Mesh) -> Mesh:
    """The boundary triangle mesh of a tetrahedral mesh, nodes renumbered.

    Node sets are restricted to the surface and renumbered; a triangle mesh is
    returned unchanged.
    """
    if mesh.cell_type == "triangle":
        return mesh
    faces = boundary_faces(mesh.cells)
    keep = np.unique(faces)
    new_index = np.full(mesh.n_nodes, -1, dtype=np.int64)
    new_index[keep] = np.arange(len(keep))
    sets = {}
    for name, idx in mesh.node_sets.items():
        mapped = new_index[idx]
        sets[name] = mapped[mapped >= 0]
    sets["surface"] = np.arange(len(keep))
    return Mesh(
        points=mesh.points[keep],
        cells=new_index[faces],
        node_sets=sets,
        axis=mesh.axis,
        name=mesh.name,
    )
