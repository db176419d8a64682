"""Element quality of a triangle or tetrahedral mesh: angles, radius ratio, altitudes.

- Smallest angle: the smallest dihedral angle of any tetrahedron (70.53
  degrees for a regular one), or the smallest interior angle of any triangle
  (60 degrees for an equilateral one).
- Radius ratio: ``d r / R`` (inradius over circumradius, ``d`` = 2 for
  triangles, 3 for tetrahedra), 1 for a regular cell and 0 for a flat one.
- Smallest altitude over the mean edge length: the distance of a vertex to the
  opposite face (or edge), the smallest over all cells, divided by the mean
  edge length. It bounds the explicit time step: the stiffness of a cell grows
  with the inverse square of its smallest altitude (0.82 for a regular
  tetrahedron, 0.87 for an equilateral triangle).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from shared.mesh import CellType, Mesh

__all__ = ["MeshQuality", "mesh_quality", "cell_angles", "radius_ratios", "altitudes"]

# Faces opposite each vertex of a tetrahedron, and the 6 edges as the pair of faces meeting there.
_OPPOSITE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
_FACE_PAIRS = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]])  # edge (i, j) is shared by faces not i, j


@dataclass(frozen=True)
class MeshQuality:
    """Quality figures of one mesh (angles in degrees, lengths in mm)."""

    cell_type: CellType
    nodes: int
    cells: int
    mean_edge: float
    min_angle: float
    min_radius_ratio: float
    p01_radius_ratio: float
    mean_radius_ratio: float
    min_altitude_ratio: float

    def summary(self) -> dict[str, float | int | str]:
        """The figures as a plain dict (JSON-ready)."""
        return asdict(self)

    def rows(self) -> list[tuple[str, str]]:
        """``(label, value)`` pairs for a table."""
        angle = "smallest dihedral angle" if self.cell_type == "tetra" else "smallest angle"
        return [
            (f"{angle} (deg)", f"{self.min_angle:.1f}"),
            ("radius ratio min / 1st pct / mean", self.radius_text()),
            ("smallest altitude / mean edge", f"{self.min_altitude_ratio:.3f}"),
        ]

    def radius_text(self) -> str:
        """``"min / 1st percentile / mean"`` radius ratio."""
        return f"{self.min_radius_ratio:.3f} / {self.p01_radius_ratio:.3f} / {self.mean_radius_ratio:.3f}"


def mesh_quality(mesh: Mesh) -> MeshQuality:
    """The :class:`MeshQuality` of ``mesh`` (triangles or tetrahedra)."""
    points, cells = mesh.points, mesh.cells.astype(np.int64)
    ratio = radius_ratios(points, cells)
    mean_edge = mesh.mean_edge_length()
    return MeshQuality(
        cell_type=mesh.cell_type,
        nodes=mesh.n_nodes,
        cells=mesh.n_cells,
        mean_edge=mean_edge,
        min_angle=float(cell_angles(points, cells).min()),
        min_radius_ratio=float(ratio.min()),
        p01_radius_ratio=float(np.percentile(ratio, 1)),
        mean_radius_ratio=float(ratio.mean()),
        min_altitude_ratio=float(altitudes(points, cells).min() / mean_edge),
    )


def cell_angles(points: NDArray[np.float64], cells: NDArray[np.integer]) -> NDArray[np.float64]:
    """(M, 3) interior angles of triangles or (M, 6) dihedral angles of tetrahedra, in degrees.

    Dihedral angles are ordered by edge (0,1), (0,2), (0,3), (1,2), (1,3), (2,3).
    """
    p = points[cells]
    if cells.shape[1] == 3:
        a = np.stack([p[:, (i + 1) % 3] - p[:, i] for i in range(3)], axis=1)  # edge i -> i+1
        b = np.stack([p[:, (i + 2) % 3] - p[:, i] for i in range(3)], axis=1)
        cos = np.einsum("mij,mij->mi", a, b) / (np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2))
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    normals = _face_normals(p)
    unit = normals / np.linalg.norm(normals, axis=2, keepdims=True)
    cos = -np.einsum("mij,mij->mi", unit[:, _FACE_PAIRS[:, 0]], unit[:, _FACE_PAIRS[:, 1]])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def radius_ratios(points: NDArray[np.float64], cells: NDArray[np.integer]) -> NDArray[np.float64]:
    """``d r / R`` per cell (1 regular, 0 flat; ``d`` = 2 for triangles, 3 for tetrahedra)."""
    p = points[cells]
    if cells.shape[1] == 3:
        a, b, c = (np.linalg.norm(p[:, (i + 1) % 3] - p[:, (i + 2) % 3], axis=1) for i in range(3))
        # 2 r / R = 2 (A / s) / (abc / 4A) = 16 A^2 / (2 s abc) = (b+c-a)(c+a-b)(a+b-c) / (abc)
        return np.maximum((b + c - a) * (c + a - b) * (a + b - c), 0.0) / (a * b * c)
    volume = np.abs(_volumes(p))
    area = np.linalg.norm(_face_normals(p), axis=2).sum(axis=1) / 2
    inradius = 3 * volume / area
    # Circumradius: 24 V R = sqrt of the product over opposite-edge products (aA + bB + cC)(...)...
    length = {(i, j): np.linalg.norm(p[:, i] - p[:, j], axis=1) for i in range(4) for j in range(i + 1, 4)}
    x, y, z = length[0, 1] * length[2, 3], length[0, 2] * length[1, 3], length[0, 3] * length[1, 2]
    product = np.maximum((x + y + z) * (x + y - z) * (x - y + z) * (-x + y + z), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = 3 * inradius * 24 * volume / np.sqrt(product)
    return np.nan_to_num(ratio, nan=0.0, posinf=0.0)


def altitudes(points: NDArray[np.float64], cells: NDArray[np.integer]) -> NDArray[np.float64]:
    """Smallest altitude of each cell (mm): vertex to opposite face (tetrahedra) or edge (triangles)."""
    p = points[cells]
    if cells.shape[1] == 3:
        twice_area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        longest = np.max([np.linalg.norm(p[:, (i + 1) % 3] - p[:, i], axis=1) for i in range(3)], axis=0)
        return twice_area / longest
    largest_face = np.linalg.norm(_face_normals(p), axis=2).max(axis=1) / 2
    return 3 * np.abs(_volumes(p)) / largest_face


def _volumes(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed volumes of tetrahedra given as (M, 4, 3) corner coordinates."""
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6


def _face_normals(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """(M, 4, 3) normals of the faces opposite each vertex, length twice the face area, pointing outward."""
    face = p[:, _OPPOSITE]  # (M, 4, 3 corners, 3)
    normals = np.cross(face[:, :, 1] - face[:, :, 0], face[:, :, 2] - face[:, :, 0])
    towards = p - face[:, :, 0]  # from the face to the opposite vertex: outward normals point away
    sign = -np.sign(np.einsum("mij,mij->mi", normals, towards))
    return normals * np.where(sign == 0, 1.0, sign)[:, :, None]
