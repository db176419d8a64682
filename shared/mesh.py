"""The mesh type: a dataclass of arrays shared by simgen and learner."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError

__all__ = [
    "Mesh",
    "LongAxis",
    "CellType",
    "NODE_SETS",
    "OPTIONAL_NODE_SETS",
    "AXIS_ARRAYS",
    "PLAUSIBLE_HEART_MM",
    "axis_from_point_data",
]

CellType = Literal["triangle", "tetra"]

#: Node sets a mesh may carry. ``surface`` is always present.
NODE_SETS = ("surface", "epicardium", "endocardium", "base")

#: Further node sets of biventricular meshes: ``endocardium`` is their union
#: (the RV septal surface counts as RV endocardium). Mesh files store them
#: under a prefixed name, as any set outside :data:`NODE_SETS`.
OPTIONAL_NODE_SETS = ("lv_endocardium", "rv_endocardium")


@dataclass(frozen=True)
class LongAxis:
    """Ventricular frame: apex point, base-centre point and the 0-degree direction.

    ``reference`` is a unit vector orthogonal to the long axis that defines the
    circumferential angle 0 of AHA segments (towards the septum/RV where known).
    """

    apex: NDArray[np.float64]
    base: NDArray[np.float64]
    reference: NDArray[np.float64]

    @property
    def direction(self) -> NDArray[np.float64]:
        """Unit vector from apex to base."""
        d = np.asarray(self.base, float) - np.asarray(self.apex, float)
        return d / np.linalg.norm(d)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.asarray(self.base) - np.asarray(self.apex)))


#: Largest bounding-box side of a heart in mm that a mesh may have, whatever unit it was read in.
PLAUSIBLE_HEART_MM = (20.0, 400.0)

#: Point-data vectors (the same at every node) that carry a mesh's long axis in its file.
AXIS_ARRAYS = ("axis_apex", "axis_base", "axis_reference")


def axis_from_point_data(point_data, n_points: int, where: str, scale: float = 1.0) -> LongAxis | None:
    """The long axis a mesh file's point data carry in :data:`AXIS_ARRAYS` (coordinates times ``scale`` mm), else
    ``None``; :class:`MeshError` naming ``where`` when they are not one finite 3-vector at every node."""
    if not all(name in point_data for name in AXIS_ARRAYS):
        return None
    rows = [np.asarray(point_data[name], np.float64).reshape(n_points, -1) for name in AXIS_ARRAYS]
    if any(r.shape[1] != 3 or not np.isfinite(r).all() or np.ptp(r, axis=0).max() > 1e-6 for r in rows):
        raise MeshError(f"{where}: point data {list(AXIS_ARRAYS)} must each be one finite 3-vector at every node")
    apex, base, reference = (r[0] for r in rows)
    return LongAxis(apex * scale, base * scale, reference)


def _unit_fibres(fibres: NDArray, n_nodes: int, name: str) -> NDArray[np.float64]:
    """``fibres`` as (N, 3) float64 unit vectors; :class:`MeshError` for another shape, non-finite or zero rows.

    Vectors already of unit length to float32 precision are kept as given, so fibres read back from float32
    (a store) are the ones written."""
    f = np.asarray(fibres, dtype=np.float64)
    if f.shape != (n_nodes, 3):
        raise MeshError(f"mesh {name!r}: fibres must have shape ({n_nodes}, 3), one vector per node, got {f.shape}")
    norm = np.linalg.norm(f, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (norm <= 0))
    if bad.size:
        raise MeshError(f"mesh {name!r}: {bad.size} fibre vector(s) zero or not finite, first nodes {bad[:5].tolist()}")
    return np.where(np.abs(norm - 1.0)[:, None] <= 1e-6, f, f / norm[:, None])


@dataclass(frozen=True)
class Mesh:
    """A triangle surface or tetrahedral volume mesh in millimetres.

    Parameters
    ----------
    points : (N, 3) float64 node coordinates.
    cells : (M, 3) or (M, 4) int32 node indices (triangles or tetrahedra).
    node_sets : named int32 index arrays (see :data:`NODE_SETS`; BiV meshes
        add :data:`OPTIONAL_NODE_SETS`); ``surface`` is required: all nodes for
        a closed triangle mesh, boundary nodes for a tetrahedral mesh.
    axis : optional ventricular frame used by regional (AHA) scar specs.
    name : identifier, used as the mesh id in stores.
    file_index : for a mesh read from a file as it is whose reading dropped
        nodes in no cell: (n_file,) the mesh node of each node of the file, -1
        for a dropped one (:meth:`to_file`, :meth:`from_file`); ``None``: the
        node ids are the file's (or the mesh was made, not read).
    fibres : optional (N, 3) unit fibre direction at each node (axial: ``f``
        and ``-f`` are one direction), tangent to a triangle surface; the
        conduction is faster along them when the solver's ``anisotropy`` is
        set (:func:`shared.fem.stiffness_matrix`).
    sheets : optional (N, 3) unit sheet direction at each node, orthogonal to
        its fibre (needs ``fibres``; made orthogonal to them where it is not
        quite); conduction along the sheets, between the fibres' and the sheet
        normal's, when the solver's ``sheet_anisotropy`` is set.
    """

    points: NDArray[np.float64]
    cells: NDArray[np.int32]
    node_sets: dict[str, NDArray[np.int32]] = field(default_factory=dict)
    axis: LongAxis | None = None
    name: str = "mesh"
    file_index: NDArray[np.int64] | None = None
    fibres: NDArray[np.float64] | None = None
    sheets: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64)
        cells = np.asarray(self.cells)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise MeshError(f"mesh {self.name!r}: points must have shape (N, 3), got {pts.shape}")
        if cells.ndim != 2 or cells.shape[1] not in (3, 4):
            raise MeshError(f"mesh {self.name!r}: cells must have shape (M, 3) or (M, 4), got {cells.shape}")
        if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
            raise MeshError(f"mesh {self.name!r}: cell node index out of range [0, {len(pts)})")
        sets = {k: np.asarray(v, dtype=np.int32) for k, v in self.node_sets.items()}
        for key, idx in sets.items():
            if idx.size and (idx.min() < 0 or idx.max() >= len(pts)):
                raise MeshError(f"mesh {self.name!r}: node set {key!r} has indices out of range")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cells", cells.astype(np.int32, copy=False))
        object.__setattr__(self, "node_sets", sets)
        if self.file_index is not None:
            index = np.asarray(self.file_index, np.int64)
            if index.ndim != 1 or not np.array_equal(np.sort(index[index >= 0]), np.arange(len(pts))):
                raise MeshError(f"mesh {self.name!r}: file_index must map file nodes onto each of its nodes once")
            object.__setattr__(self, "file_index", index)
        if self.fibres is not None:
            object.__setattr__(self, "fibres", _unit_fibres(self.fibres, len(pts), self.name))
        if self.sheets is not None:
            if self.fibres is None:
                raise MeshError(f"mesh {self.name!r}: sheets need fibres (each sheet lies across its fibre)")
            sheets = np.asarray(self.sheets, dtype=np.float64)
            if sheets.shape == (len(pts), 3):  # the part orthogonal to the fibre, where float32 does not give it
                along = np.einsum("nd,nd->n", sheets, self.fibres)
                sheets = np.where(np.abs(along)[:, None] <= 1e-6, sheets, sheets - along[:, None] * self.fibres)
            object.__setattr__(self, "sheets", _unit_fibres(sheets, len(pts), self.name))

    @property
    def n_nodes(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @property
    def cell_type(self) -> CellType:
        return "triangle" if self.cells.shape[1] == 3 else "tetra"

    def nodes(self, name: str) -> NDArray[np.int32]:
        """Indices of a named node set; a clear error if the mesh lacks it."""
        try:
            return self.node_sets[name]
        except KeyError:
            raise MeshError(f"mesh {self.name!r} has no node set {name!r} (has: {sorted(self.node_sets)})") from None

    def edges(self) -> NDArray[np.int32]:
        """Unique undirected edges (E, 2), sorted, lower index first."""
        k = self.cells.shape[1]
        pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
        e = np.concatenate([self.cells[:, [i, j]] for i, j in pairs])
        e.sort(axis=1)
        key = np.unique(e[:, 0].astype(np.int64) * self.n_nodes + e[:, 1])  # 1-D keys: 10x faster than axis=0
        return np.stack([key // self.n_nodes, key % self.n_nodes], axis=1).astype(np.int32)

    def from_file(self, ids: NDArray[np.integer]) -> NDArray[np.int64]:
        """This mesh's nodes of the file's node ``ids`` (the same ids where no node was dropped)."""
        ids = np.asarray(ids, np.int64)
        if self.file_index is None:
            return ids
        bad = ids[(ids < 0) | (ids >= len(self.file_index))]
        dropped = ids[(ids >= 0) & (ids < len(self.file_index))]
        dropped = dropped[self.file_index[dropped] < 0]
        if bad.size or dropped.size:
            what = f"node(s) {bad[:5].tolist()} are not nodes of the file" if bad.size else ""
            what = what or f"node(s) {dropped[:5].tolist()} of the file are in no cell (they carry no tissue)"
            raise MeshError(f"mesh {self.name!r}: {what}")
        return self.file_index[ids]

    def file_ids(self, nodes: NDArray[np.integer]) -> NDArray[np.int64]:
        """The file's node id of each of this mesh's ``nodes`` (the inverse of :meth:`from_file`)."""
        nodes = np.asarray(nodes, np.int64)
        return nodes if self.file_index is None else np.flatnonzero(self.file_index >= 0)[nodes]

    def to_file(self, values: NDArray, fill: float = np.nan) -> NDArray:
        """Per-node ``values`` (..., N) laid out on the file's nodes (..., n_file), ``fill`` at dropped ones."""
        values = np.asarray(values)
        if self.file_index is None:
            return values
        kept = self.file_index >= 0
        out = np.full((*values.shape[:-1], len(self.file_index)), fill, dtype=np.result_type(values, type(fill)))
        out[..., kept] = values[..., self.file_index[kept]]
        return out

    def mean_edge_length(self) -> float:
        e = self.edges()
        return float(np.linalg.norm(self.points[e[:, 0]] - self.points[e[:, 1]], axis=1).mean())
