"""Anatomical labels a mesh file carries, and how well detected node sets agree with them.

Files made for cardiac simulation often mark the heart's surfaces. Three
forms are read (:func:`file_labels`), each into the node sets ``base``,
``epicardium``, ``endocardium`` and, with both ventricles,
``lv_endocardium`` and ``rv_endocardium`` (``endocardium`` is their union):

- **Facet markers**: an integer cell-data array (:data:`MARKER_KEYS`, e.g.
  gmsh's ``gmsh:physical`` or medit's ``medit:ref``) on the boundary
  triangles of a tetrahedral mesh, or on the triangles of a surface. A node
  belongs to a label when it is a corner of a triangle with that marker, so
  nodes on the line between two labels belong to both. Markers are mapped
  by their names where the file names them (gmsh physical names, read
  through :data:`LABEL_NAMES`: ``EPI``, ``ENDO_LV``, ``LV``, ...), else by
  the numbers the FEniCS meshes of ldrb and cardiac-geometries use
  (:data:`FENICS_MARKERS`: ``BASE=10``, ``ENDO_RV=20``, ``ENDO_LV=30``,
  ``EPI=40``).
- **Class arrays**: an array of one class per surface triangle (cell data)
  or per node (point data) (:data:`CLASS_ARRAYS`, e.g. Cobiveco's ``class``:
  1 base, 2 epicardium, 3 LV, 4 RV endocardium). Where a file has both, the
  triangles' are read (a node on the line between two classes belongs to
  both, as with markers). Values that are no class (a stray value on a few
  nodes or triangles) are named with their count in a warning and read as
  unlabelled; more than :data:`MAX_STRAY` of them make the array no class
  array, which is refused.
- 0/1 point-data masks under the node sets' own names are read by
  :func:`simgen.meshes.io.load_mesh` itself.

Markers that cannot be mapped (no name and not the FEniCS numbers, or
names none of which is a heart surface) raise :class:`MeshError` saying how
to give the sets instead; named markers that are no heart surface (a valve,
a ring) are skipped when others are.

:func:`label_agreement` measures detection against labels: the share of the
surface nodes of each label that the other sets tag with the same label.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

import meshio
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.topology import boundary_faces

__all__ = [
    "LABEL_NAMES",
    "FENICS_MARKERS",
    "MARKER_KEYS",
    "CLASS_ARRAYS",
    "SURFACE_LABELS",
    "file_labels",
    "label_agreement",
    "surface_labels",
]

log = logging.getLogger("simgen.meshes")

#: Node set of each marker name a file may use (lower case; ``-``, spaces and dots read as ``_``).
LABEL_NAMES: dict[str, str] = {
    **dict.fromkeys(["base", "base_plane", "basal_plane", "top"], "base"),
    **dict.fromkeys(["epi", "epicardium", "epicardial", "left_ventricle_epicardium"], "epicardium"),
    **dict.fromkeys(["endo", "endocardium", "endocardial"], "endocardium"),
    **dict.fromkeys(
        ["lv", "endo_lv", "lv_endo", "endolv", "lv_endocardium", "left_ventricle_endocardium", "lv_septum"],
        "lv_endocardium",
    ),
    **dict.fromkeys(
        ["rv", "endo_rv", "rv_endo", "endorv", "rv_endocardium", "right_ventricle_endocardium", "rv_septum"],
        "rv_endocardium",
    ),
}
#: Facet marker numbers of the FEniCS meshes of ldrb and cardiac-geometries (an LV has no 20).
FENICS_MARKERS: dict[int, str] = {10: "base", 20: "rv_endocardium", 30: "lv_endocardium", 40: "epicardium"}
#: Cell-data arrays read as facet markers, in this order.
MARKER_KEYS = ("gmsh:physical", "medit:ref", "markers", "facet_markers", "boundaries", "ffun", "name_to_read")
#: Point-data arrays of one class per node, and the node set of each class.
CLASS_ARRAYS: dict[str, dict[int, str]] = {
    "class": {1: "base", 2: "epicardium", 3: "lv_endocardium", 4: "rv_endocardium"},
}
#: Largest share of a class array's values that may be no class (read as unlabelled, with a warning).
MAX_STRAY = 0.01
#: Labels :func:`label_agreement` compares, in table order.
SURFACE_LABELS = ("base", "epicardium", "endocardium", "lv_endocardium", "rv_endocardium")


def file_labels(raw: meshio.Mesh, path: Path) -> dict[str, NDArray[np.bool_]]:
    """The heart node sets a file's markers or class array give, as masks over its nodes; ``{}`` if none.

    See the module docstring; :class:`MeshError` names the file and its
    markers when they cannot be mapped.
    """
    n = len(raw.points)
    blocks = [i for i, block in enumerate(raw.cells) if block.type == "triangle"]
    for key, classes in CLASS_ARRAYS.items():
        if key in raw.cell_data and blocks:
            triangles = np.concatenate([raw.cells[i].data for i in blocks]).astype(np.int64)
            values = np.concatenate([np.asarray(raw.cell_data[key][i]).reshape(-1) for i in blocks])
            per_triangle = _class_masks(values, classes, f"cell data {key!r}", len(triangles), path, "triangles")
            return _complete({name: _nodes_of(triangles[mask], n) for name, mask in per_triangle.items()})
        if key in raw.point_data:
            return _complete(_class_masks(np.asarray(raw.point_data[key]), classes, f"point data {key!r}", n, path))
    key = next((k for k in MARKER_KEYS if k in raw.cell_data), None)
    if key is None or not blocks:
        return {}
    triangles = np.concatenate([raw.cells[i].data for i in blocks]).astype(np.int64)
    values = np.concatenate([np.asarray(raw.cell_data[key][i]).reshape(-1) for i in blocks])
    if not np.all(np.isfinite(values)) or not np.all(values == np.round(values)):
        raise MeshError(f"{path}: facet markers {key!r} are not integers")
    values = values.astype(np.int64)
    masks: dict[str, NDArray[np.bool_]] = {}
    for value, name in _marker_sets(np.unique(values), _marker_names(raw.field_data), key, path).items():
        mask = masks.setdefault(name, np.zeros(n, dtype=bool))
        mask[triangles[values == value].ravel()] = True
    return _complete(masks)


def _nodes_of(triangles: NDArray[np.int64], n: int) -> NDArray[np.bool_]:
    mask = np.zeros(n, dtype=bool)
    mask[triangles.ravel()] = True
    return mask


def _class_masks(
    values: NDArray, classes: Mapping[int, str], what: str, n: int, path: Path, items: str = "nodes"
) -> dict[str, NDArray[np.bool_]]:
    """Masks of an array of one class per node (or triangle: ``items``); values outside ``classes`` are
    unlabelled (named in a warning), and :class:`MeshError` when more than :data:`MAX_STRAY` of them are."""
    values = values.reshape(n, -1)[:, 0] if values.size == n else values
    stray = ~np.isin(values, list(classes)) if values.shape == (n,) else np.ones(1, bool)
    if values.shape != (n,) or stray.mean() > MAX_STRAY:
        raise MeshError(
            f"{path}: {what} holds classes {sorted(set(np.unique(values).tolist()))}; it is read as one class per "
            f"{items[:-1]} of { {k: v for k, v in classes.items()} } (rename the array, or give the sets as 0/1 masks)"
        )
    if stray.any():
        log.warning(
            "%s: %s: %d of %d %s hold no class of %s (values %s): read as unlabelled",
            path,
            what,
            int(stray.sum()),
            n,
            items,
            sorted(classes),
            sorted(set(np.unique(values[stray]).tolist()))[:5],
        )
    return {name: values == value for value, name in classes.items() if (values == value).any()}


def _marker_names(field_data: Mapping[str, NDArray]) -> dict[int, str]:
    """Marker number -> name of the file's named surface groups (gmsh ``$PhysicalNames`` of dimension 2)."""
    names = {}
    for name, value in field_data.items():
        value = np.asarray(value).reshape(-1)
        if value.size == 2 and value[1] == 2:
            names[int(value[0])] = name
    return names


def _normal(name: str) -> str:
    return name.strip().lower().replace("-", "_").replace(" ", "_").replace(".", "_")


def _marker_sets(values: NDArray[np.int64], names: dict[int, str], key: str, path: Path) -> dict[int, str]:
    """Node set of each marker number in the file (see the module docstring)."""
    hint = (
        "give the heart's node sets as 0/1 point-data masks (node_set_arrays), or name the markers "
        f"(one of {sorted(set(LABEL_NAMES))})"
    )
    if names:
        found = {int(v): LABEL_NAMES.get(_normal(names.get(int(v), ""))) for v in values}
        mapped = {v: name for v, name in found.items() if name}
        if not mapped:
            named = {int(v): names.get(int(v)) for v in values}
            raise MeshError(f"{path}: no facet marker {key!r} names a heart surface (markers {named}): {hint}")
        skipped = sorted(names.get(v, str(v)) for v in found if v not in mapped)
        if skipped:
            log.info("%s: facet markers %s are no heart surface, skipped", path, skipped)
        return mapped
    if set(values.tolist()) <= set(FENICS_MARKERS):
        return {int(v): FENICS_MARKERS[int(v)] for v in values}
    raise MeshError(
        f"{path}: facet markers {key!r} {values.tolist()} have no names and are not the FEniCS numbers "
        f"{ {v: k for k, v in FENICS_MARKERS.items()} }: {hint}"
    )


def _complete(masks: dict[str, NDArray[np.bool_]]) -> dict[str, NDArray[np.bool_]]:
    """``endocardium`` as the union of the ventricles'; an LV alone keeps only ``endocardium``."""
    if not masks:
        return masks
    lv, rv = masks.get("lv_endocardium"), masks.get("rv_endocardium")
    parts = [m for m in (masks.get("endocardium"), lv, rv) if m is not None]
    if parts:
        masks["endocardium"] = np.logical_or.reduce(parts)
    if lv is None or rv is None:
        masks.pop("lv_endocardium", None)
        masks.pop("rv_endocardium", None)
    return masks


def surface_labels(mesh: Mesh, sets: Mapping[str, NDArray[np.integer]]) -> dict[str, NDArray[np.bool_]]:
    """The :data:`SURFACE_LABELS` among ``sets`` as masks over the mesh's nodes."""
    masks = {}
    for name in SURFACE_LABELS:
        if name in sets:
            masks[name] = np.zeros(mesh.n_nodes, dtype=bool)
            masks[name][np.asarray(sets[name], np.int64)] = True
    return masks


def _surface_neighbours(mesh: Mesh) -> coo_matrix:
    """Node adjacency along the boundary surface's edges (not through the volume)."""
    faces = boundary_faces(mesh.cells) if mesh.cell_type == "tetra" else mesh.cells
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = mesh.n_nodes
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return (graph + graph.T).tocsr()


def label_agreement(
    mesh: Mesh,
    truth: Mapping[str, NDArray[np.integer]],
    detected: Mapping[str, NDArray[np.integer]],
    near: bool = True,
) -> dict[str, float]:
    """Share of each label's nodes in ``truth`` that ``detected`` tags with the same label.

    Labels are those of :data:`SURFACE_LABELS` in ``truth``; a BiV's truth
    is compared on ``lv_endocardium`` and ``rv_endocardium`` rather than on
    their union. A node is tagged right when a detected set holding it is
    one of its own labels (nodes on the line between two labels have both)
    or, with ``near``, a label of a node one surface edge away: the line
    between two labels may pass a node either way. Where ``truth`` has no
    ``base`` (a mesh open at its valve rings), detected base nodes count as
    epicardium, the rest of the outer surface.
    """
    names = [k for k in SURFACE_LABELS if k in truth]
    if {"lv_endocardium", "rv_endocardium"} <= set(names):
        names.remove("endocardium")
    true, found = surface_labels(mesh, truth), surface_labels(mesh, detected)
    if "base" not in true and "base" in found and "epicardium" in found:  # no base in the file: it is epicardium
        found["epicardium"] = found["epicardium"] | found.pop("base")
    own = np.stack([true[k] for k in names], axis=1)
    accepted = own | (_surface_neighbours(mesh) @ own.astype(np.int64) > 0) if near else own
    tagged = np.stack([found.get(k, np.zeros(mesh.n_nodes, dtype=bool)) for k in names], axis=1)
    right = (tagged & accepted).any(axis=1)
    return {k: float(right[own[:, j]].mean()) if own[:, j].any() else float("nan") for j, k in enumerate(names)}
