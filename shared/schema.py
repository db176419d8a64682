"""The dataset store contract (Zarr v3), shared by simgen (writer) and learner (reader).

Layout of one store (one dataset)::

    <store>/                      attrs: schema_version, spec (build spec as JSON-able dict), spec_hash
      meshes/<mesh_id>/           attrs: name, cell_type, axis (apex/base/reference or null)
        points (node, xyz) f8     cells (cell, vertex) i4
        surface / epicardium / endocardium / base / electrodes (k,) i4   observed-node index sets
        stim_nodes (site,) i4     stimulation sites of every subject on this mesh
      subjects/<subject_id>/      attrs: mesh_id, tissue (TissueSpec as dict), chunk_sites
        a, D (node,) f4           label (node,) i1
        u (site, time, node) f4   chunked along site: one chunk = one build task
        activation (site, node) f4  first crossing of the activation threshold (NaN = never), time units
        times (time,) f8          done (chunk,) u1: 1 once a chunk's u and activation are written

Rules: ``done[k]`` is written only after chunk ``k``'s data; readers must treat a
chunk with ``done == 0`` as missing. Any Zarr v3 reader (zarr, xarray through
``dimension_names``) opens the store without simgen.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from shared.errors import SchemaError

__all__ = [
    "SCHEMA_VERSION",
    "ArraySpec",
    "MESH_ARRAYS",
    "MESH_INDEX_SETS",
    "SUBJECT_ARRAYS",
    "mesh_path",
    "subject_path",
    "check_schema_version",
]

#: Bumped on any incompatible change of names, dtypes or dimensions below.
SCHEMA_VERSION = 1


@dataclass(frozen=True)
class ArraySpec:
    """Name, dtype and dimension names of one array."""

    dtype: str
    dims: tuple[str, ...]


#: Index sets of nodes stored per mesh (observation operators read these).
MESH_INDEX_SETS = ("surface", "epicardium", "endocardium", "base", "electrodes")

MESH_ARRAYS: dict[str, ArraySpec] = {
    "points": ArraySpec("float64", ("node", "xyz")),
    "cells": ArraySpec("int32", ("cell", "vertex")),
    "stim_nodes": ArraySpec("int32", ("site",)),
    **{name: ArraySpec("int32", (f"{name}_node",)) for name in MESH_INDEX_SETS},
}

SUBJECT_ARRAYS: dict[str, ArraySpec] = {
    "a": ArraySpec("float32", ("node",)),
    "D": ArraySpec("float32", ("node",)),
    "label": ArraySpec("int8", ("node",)),
    "u": ArraySpec("float32", ("site", "time", "node")),
    "activation": ArraySpec("float32", ("site", "node")),
    "times": ArraySpec("float64", ("time",)),
    "done": ArraySpec("uint8", ("chunk",)),
}


def mesh_path(mesh_id: str) -> str:
    """Group path of a mesh."""
    return f"meshes/{mesh_id}"


def subject_path(subject_id: str) -> str:
    """Group path of a subject."""
    return f"subjects/{subject_id}"


def check_schema_version(attrs: Mapping[str, Any], where: str = "store") -> None:
    """Raise :class:`SchemaError` unless ``attrs`` carry this module's schema version."""
    version = attrs.get("schema_version")
    if version is None:
        raise SchemaError(f"{where} has no schema_version attribute: not a simgen dataset store")
    if version != SCHEMA_VERSION:
        raise SchemaError(
            f"{where} has schema_version {version}, this code reads version {SCHEMA_VERSION}; "
            "rebuild the store or use a matching release"
        )
