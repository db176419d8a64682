"""Mesh topology helpers: boundary faces, surface extraction, sub-meshes."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from shared.mesh import Mesh

__all__ = ["tet_faces", "boundary_faces", "extract_surface", "signed_volumes"]

# Faces of tetrahedron (a, b, c, d) oriented outward when its volume is positive.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def signed_volumes(points: NDArray[np.float64], tets: NDArray[np.integer]) -> NDArray[np.float64]:
    """Signed volume of each tetrahedron (positive for right-handed ordering)."""
    p = points[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6


def tet_faces(tets: NDArray[np.integer]) -> NDArray[np.int32]:
    """All faces (4M, 3), outward-oriented for positively oriented tets."""
    return tets[:, _TET_FACES].reshape(-1, 3).astype(np.int32)


def boundary_faces(tets: NDArray[np.integer]) -> NDArray[np.int32]:
    """Faces that belong to exactly one tetrahedron, keeping their outward orientation."""
    faces = tet_faces(tets)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


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
