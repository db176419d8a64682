"""Mesh files: read any format meshio reads, write cells plus node-set masks.

Node sets travel as point-data masks (1 = member): the standard sets of
:data:`shared.mesh.NODE_SETS` under their own names (so files from other
tools that mark, e.g., ``epicardium`` are understood), any other set under
``nodeset:<name>``; ``node_set_arrays`` names other masks of a file as sets.
Heart labels in other forms (facet markers such as gmsh physical groups on
the boundary triangles, a class per node) are read too
(:func:`simgen.meshes.labels.file_labels`); masks take precedence.
``surface`` is always recomputed on load. meshio formats carry no field data,
so the long axis travels as three point-data vectors, the same at every node
(:data:`AXIS_ARRAYS`: apex, base centre, angle-0 direction), read back when
``axis=`` gives none.

Coordinates are converted to millimetres (:mod:`simgen.meshes.units`;
:func:`save_mesh` writes the constant point-data array ``mm_per_unit``) and
the cells repaired where that is safe (:mod:`simgen.meshes.repair`), each
repair logged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from os import PathLike
from pathlib import Path

import meshio
import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError
from shared.mesh import AXIS_ARRAYS, NODE_SETS, LongAxis, Mesh, axis_from_point_data
from simgen.meshes.labels import file_labels
from simgen.meshes.repair import drop_unused_nodes, orient_triangles, remove_degenerate_cells, split_hexahedra
from simgen.meshes.topology import boundary_faces
from simgen.meshes.units import UNIT_KEY, file_units, mm_per_unit
from simgen.meshes.validate import refuse_parts, validate_mesh

__all__ = ["AXIS_ARRAYS", "FIBRE_KEYS", "SHEET_KEYS", "load_mesh", "save_mesh"]

#: Point data holding a fibre direction per node, read in this order; :func:`save_mesh` writes the first.
FIBRE_KEYS = ("fibre", "fibres", "fiber", "fibers")
#: Point data holding a sheet direction per node (with fibres only), read in this order.
SHEET_KEYS = ("sheet", "sheets")

_PREFIX = "nodeset:"
_IGNORED = {"vertex", "line", "line3"}  # lower-dimensional markers (e.g. gmsh physical groups)
_FORMAT = {".msh": "gmsh"}  # meshio would pick gmsh22 ASCII, which loses point data
_SURFACE_ONLY = {".stl", ".obj", ".off", ".ply"}
# Cell types used, in order of preference, with the lower-dimensional types then taken as markers.
_KINDS = {"tetra": {"triangle", "quad"}, "hexahedron": {"quad"}, "triangle": set()}
log = logging.getLogger("simgen.meshes")


def load_mesh(
    path: str | PathLike,
    name: str | None = None,
    axis: LongAxis | None = None,
    units: str | None = None,
    node_set_arrays: Mapping[str, str] | None = None,
    heart: bool = True,
) -> Mesh:
    """Read a triangle, tetrahedral or hexahedral mesh in mm, repair it where safe and validate it.

    Parameters
    ----------
    path : any file meshio reads (.vtu, .vtk, .msh, .obj, .stl, .ply, .xdmf, ...).
    name : mesh name; defaults to the file stem.
    axis : optional ventricular frame to attach (files carry none), in mm.
    units : ``"mm"``, ``"cm"`` or ``"m"``; ``None``: the file's, else, for a
        ``heart``, inferred from the extent of the nodes in cells, else mm
        (:func:`simgen.meshes.units.mm_per_unit`).
    node_set_arrays : node set name -> name of the file's 0/1 point-data array
        holding it (e.g. ``{"epicardium": "EPI"}``).

    Tetrahedra are used when present (triangles and lines are then taken as
    boundary markers and ignored), else hexahedra (split into tetrahedra),
    else triangles. Degenerate cells are removed, nodes referenced by no kept
    cell dropped (both with a logged note giving the indices and the
    renumbering) and triangles oriented consistently outward. Raises
    :class:`MeshError` naming the file if it is missing, unreadable, has no
    usable cells, has ambiguous units or fails
    :func:`~simgen.meshes.validate.validate_mesh`.
    """
    path = Path(path)
    raw = _read(path)
    where = str(path)
    points = np.asarray(raw.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise MeshError(f"{path}: points must have 2 or 3 coordinates, got shape {points.shape}")
    if points.shape[1] == 2:
        points = np.hstack([points, np.zeros((len(points), 1))])
    kind, cells = _select_cells(raw, path)
    _check_indices(cells, len(points), path)
    declared = file_units(raw.field_data, raw.point_data, where)
    try:
        scale, origin = mm_per_unit(points[np.unique(cells)], declared, units, where, infer=heart)
    except MeshError:
        refuse_parts(cells, len(points), where)  # pieces far apart fit no unit: name the pieces instead
        raise
    if scale != 1.0:
        points = points * scale
        (log.warning if origin == "inferred" else log.info)(
            "%s: coordinates x %g to mm (unit %s)", where, scale, origin
        )
    if kind == "hexahedron":
        cells = split_hexahedra(points, cells, where)

    masks = {
        key: _mask(raw.point_data[array], len(points), array, path)
        for key, array in _set_arrays(raw, node_set_arrays, path).items()
    }
    masks = {**_labels(raw, masks, path), **masks}
    cells = remove_degenerate_cells(points, cells, where)
    points, cells, kept = drop_unused_nodes(points, cells, where)
    if cells.shape[1] == 3:
        cells = orient_triangles(points, cells, where)
    node_sets = {key: np.flatnonzero(mask[kept]) for key, mask in masks.items()}
    node_sets["surface"] = np.arange(len(points)) if cells.shape[1] == 3 else np.unique(boundary_faces(cells))
    if axis is None:
        axis = axis_from_point_data(raw.point_data, len(raw.points), str(path), scale)
    fibres, sheets = _file_vectors(raw, path, FIBRE_KEYS), _file_vectors(raw, path, SHEET_KEYS)
    file_index = None
    if len(kept) < len(raw.points):  # nodes in no cell were dropped: keep the way back to the file's ids
        file_index = np.full(len(raw.points), -1, np.int64)
        file_index[kept] = np.arange(len(kept))
    try:
        mesh = Mesh(
            points,
            cells,
            node_sets,
            axis,
            name or path.stem,
            file_index,
            None if fibres is None else fibres[kept],
            None if sheets is None or fibres is None else sheets[kept],
        )
        return validate_mesh(mesh)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from exc


def _read(path: Path) -> meshio.Mesh:
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    try:
        with np.errstate(over="ignore"):  # meshio's STL sniffing overflows on ASCII files
            return meshio.read(path)
    except (Exception, SystemExit) as exc:  # meshio raises many types, and exits on unknown content
        reason = str(exc) if not isinstance(exc, SystemExit) else "not a readable mesh in this format"
        raise MeshError(f"cannot read mesh file {path}: {reason}") from exc


def save_mesh(mesh: Mesh, path: str | PathLike, point_data: Mapping[str, NDArray] | None = None) -> Path:
    """Write ``mesh`` with its node sets as 0/1 point data, and any further ``point_data``; returns the path.

    Formats without point data (.stl, .obj, .off) keep the geometry only;
    surface-only formats refuse tetrahedral meshes.
    """
    path = Path(path)
    if mesh.cell_type == "tetra" and path.suffix.lower() in _SURFACE_ONLY:
        raise MeshError(f"cannot write {path}: {path.suffix} files hold no tetrahedra (use .vtu or .msh)")
    data = {UNIT_KEY: np.ones(mesh.n_nodes, dtype=np.float32)}  # coordinates are mm
    for key, idx in mesh.node_sets.items():
        mask = np.zeros(mesh.n_nodes, dtype=np.uint8)
        mask[idx] = 1
        data[key if key in NODE_SETS else _PREFIX + key] = mask
    if mesh.fibres is not None:
        data[FIBRE_KEYS[0]] = mesh.fibres
    if mesh.sheets is not None:
        data[SHEET_KEYS[0]] = mesh.sheets
    if mesh.axis is not None:
        for name, value in zip(AXIS_ARRAYS, (mesh.axis.apex, mesh.axis.base, mesh.axis.reference)):
            data[name] = np.tile(np.asarray(value, np.float64), (mesh.n_nodes, 1))
    data.update(point_data or {})
    raw = meshio.Mesh(mesh.points, [(mesh.cell_type, mesh.cells)], point_data=data)
    try:
        meshio.write(path, raw, file_format=_FORMAT.get(path.suffix.lower()))
    except Exception as exc:
        raise MeshError(f"cannot write mesh file {path}: {exc}") from exc
    return path


def _select_cells(raw: meshio.Mesh, path: Path) -> tuple[str, NDArray[np.int64]]:
    """The volume or surface cells to use, ``(cell type, cells)``; markers of lower dimension are ignored."""
    types = {block.type for block in raw.cells}
    for kind in _KINDS:
        if kind in types:
            break
    else:
        found = ", ".join(sorted(types)) or "none"
        raise MeshError(f"{path}: no linear tetrahedra, hexahedra or triangles (cell types: {found})")
    other = types - {kind} - _KINDS[kind] - _IGNORED
    if other:
        raise MeshError(
            f"{path}: mixed cell types are unsupported ({kind} with {', '.join(sorted(other))}); "
            "convert the mesh to pure linear tetrahedra, hexahedra or triangles"
        )
    return kind, np.concatenate([block.data for block in raw.cells if block.type == kind]).astype(np.int64)


def _check_indices(cells: NDArray[np.int64], n: int, path: Path) -> None:
    """Refuse cells that refer to nodes outside ``[0, n)``, naming the first such cell."""
    bad = np.flatnonzero(((cells < 0) | (cells >= n)).any(axis=1))
    if bad.size:
        raise MeshError(
            f"{path}: cell node index out of range [0, {n}): {bad.size} cell(s), "
            f"first cell {bad[0]} with nodes {cells[bad[0]].tolist()}"
        )


def _set_arrays(raw: meshio.Mesh, node_set_arrays: Mapping[str, str] | None, path: Path) -> dict[str, str]:
    """Node set name -> point-data array holding it: the file's own sets, then ``node_set_arrays``."""
    names = {
        key.removeprefix(_PREFIX): key
        for key in raw.point_data
        if (key in NODE_SETS and key != "surface") or key.startswith(_PREFIX)
    }
    for set_name, array in (node_set_arrays or {}).items():
        if array not in raw.point_data:
            raise MeshError(
                f"{path}: no point-data array {array!r} for node set {set_name!r} (has: {sorted(raw.point_data)})"
            )
        names[set_name] = array
    return names


def _labels(raw: meshio.Mesh, masks: Mapping[str, NDArray], path: Path) -> dict[str, NDArray[np.bool_]]:
    """The file's heart labels (:func:`~simgen.meshes.labels.file_labels`); unmappable ones refused only
    where the masks do not already give the epicardium and endocardium."""
    try:
        return file_labels(raw, path)
    except MeshError:
        if {"epicardium", "endocardium"} <= set(masks):
            return {}
        raise


def _mask(values: NDArray, n: int, key: str, path: Path) -> NDArray[np.bool_]:
    values = np.asarray(values)
    if values.ndim == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.shape != (n,) or values.dtype.kind not in "biuf" or not np.isin(values, (0, 1)).all():
        raise MeshError(f"{path}: point data {key!r} is not a 0/1 node mask of length {n}")
    return values.astype(bool)


def _file_vectors(raw: meshio.Mesh, path: Path, keys: tuple[str, ...]) -> NDArray[np.float64] | None:
    """A direction at each node of the file (the point data of ``keys``: fibres, sheets), else ``None``; two
    arrays of ``keys`` that differ (beyond a direction's sign) are refused, naming both."""
    found = [k for k in keys if k in raw.point_data]
    if not found:
        return None
    key = found[0]
    vectors = np.asarray(raw.point_data[key], np.float64)
    if vectors.shape != (len(raw.points), 3):
        raise MeshError(f"{path}: point data {key!r} must be one 3-vector per node, got shape {vectors.shape}")
    for other in found[1:]:
        b = np.asarray(raw.point_data[other], np.float64)
        if b.shape != vectors.shape or not (np.isclose(b, vectors).all(1) | np.isclose(b, -vectors).all(1)).all():
            raise MeshError(
                f"{path}: point data {key!r} and {other!r} both give a direction per node and differ: which one is "
                "meant cannot be told; keep one of them in the file"
            )
    return vectors
