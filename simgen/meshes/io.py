"""Mesh files: read any format meshio reads, write cells plus node-set masks.

Node sets travel as point-data masks (1 = member): the standard sets of
:data:`shared.mesh.NODE_SETS` under their own names (so files from other
tools that mark, e.g., ``epicardium`` are understood), any other set under
``nodeset:<name>``. ``surface`` is always recomputed on load. meshio formats
cannot carry the long axis; pass ``axis=`` to :func:`load_mesh` when needed.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import meshio
import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError
from shared.mesh import NODE_SETS, LongAxis, Mesh
from simgen.meshes.topology import boundary_faces
from simgen.meshes.validate import validate_mesh

__all__ = ["load_mesh", "save_mesh"]

_PREFIX = "nodeset:"
_IGNORED = {"vertex", "line", "line3"}  # lower-dimensional markers (e.g. gmsh physical groups)
_FORMAT = {".msh": "gmsh"}  # meshio would pick gmsh22 ASCII, which loses point data
_SURFACE_ONLY = {".stl", ".obj", ".off", ".ply"}


def load_mesh(path: str | PathLike, name: str | None = None, axis: LongAxis | None = None) -> Mesh:
    """Read a triangle or tetrahedral mesh and validate it.

    Parameters
    ----------
    path : any file meshio reads (.vtu, .vtk, .msh, .obj, .stl, .ply, .xdmf, ...).
    name : mesh name; defaults to the file stem.
    axis : optional ventricular frame to attach (files carry none).

    Tetrahedra are used when present (triangles and lines are then taken as
    boundary markers and ignored), else triangles. Nodes referenced by no kept
    cell are dropped and node sets renumbered. Raises :class:`MeshError` naming
    the file if it is missing, unreadable, has no usable cells or fails
    :func:`~simgen.meshes.validate.validate_mesh`.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    try:
        with np.errstate(over="ignore"):  # meshio's STL sniffing overflows on ASCII files
            raw = meshio.read(path)
    except (Exception, SystemExit) as exc:  # meshio raises many types, and exits on unknown content
        reason = str(exc) if not isinstance(exc, SystemExit) else "not a readable mesh in this format"
        raise MeshError(f"cannot read mesh file {path}: {reason}") from exc
    cells = _select_cells(raw, path)
    points = np.asarray(raw.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise MeshError(f"{path}: points must have 2 or 3 coordinates, got shape {points.shape}")
    if points.shape[1] == 2:
        points = np.hstack([points, np.zeros((len(points), 1))])

    masks = {key: _mask(raw.point_data[key], len(points), key, path) for key in _set_names(raw.point_data)}
    keep = np.unique(cells)
    new_index = np.full(len(points), -1, dtype=np.int64)
    new_index[keep] = np.arange(len(keep))
    cells = new_index[cells]
    node_sets = {key.removeprefix(_PREFIX): np.flatnonzero(mask[keep]) for key, mask in masks.items()}
    node_sets["surface"] = np.arange(len(keep)) if cells.shape[1] == 3 else np.unique(boundary_faces(cells))
    try:
        mesh = Mesh(points=points[keep], cells=cells, node_sets=node_sets, axis=axis, name=name or path.stem)
        return validate_mesh(mesh)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from exc


def save_mesh(mesh: Mesh, path: str | PathLike) -> Path:
    """Write ``mesh`` with its node sets as 0/1 point data; returns the path.

    Formats without point data (.stl, .obj, .off) keep the geometry only;
    surface-only formats refuse tetrahedral meshes.
    """
    path = Path(path)
    if mesh.cell_type == "tetra" and path.suffix.lower() in _SURFACE_ONLY:
        raise MeshError(f"cannot write {path}: {path.suffix} files hold no tetrahedra (use .vtu or .msh)")
    point_data = {}
    for key, idx in mesh.node_sets.items():
        mask = np.zeros(mesh.n_nodes, dtype=np.uint8)
        mask[idx] = 1
        point_data[key if key in NODE_SETS else _PREFIX + key] = mask
    raw = meshio.Mesh(mesh.points, [(mesh.cell_type, mesh.cells)], point_data=point_data)
    try:
        meshio.write(path, raw, file_format=_FORMAT.get(path.suffix.lower()))
    except Exception as exc:
        raise MeshError(f"cannot write mesh file {path}: {exc}") from exc
    return path


def _select_cells(raw: meshio.Mesh, path: Path) -> NDArray[np.int64]:
    types = {block.type for block in raw.cells}
    if "tetra" in types:
        kind, allowed = "tetra", {"tetra", "triangle", "quad"} | _IGNORED
    elif "triangle" in types:
        kind, allowed = "triangle", {"triangle"} | _IGNORED
    else:
        found = ", ".join(sorted(types)) or "none"
        raise MeshError(f"{path}: no linear tetrahedra or triangles (cell types: {found})")
    other = types - allowed
    if other:
        raise MeshError(
            f"{path}: mixed cell types are unsupported ({kind} with {', '.join(sorted(other))}); "
            "convert the mesh to pure linear tetrahedra or triangles"
        )
    return np.concatenate([block.data for block in raw.cells if block.type == kind]).astype(np.int64)


def _set_names(point_data: dict) -> list[str]:
    return [key for key in point_data if (key in NODE_SETS and key != "surface") or key.startswith(_PREFIX)]


def _mask(values: NDArray, n: int, key: str, path: Path) -> NDArray[np.bool_]:
    values = np.asarray(values)
    if values.ndim == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.shape != (n,) or values.dtype.kind not in "biuf" or not np.isin(values, (0, 1)).all():
        raise MeshError(f"{path}: point data {key!r} is not a 0/1 node mask of length {n}")
    return values.astype(bool)
