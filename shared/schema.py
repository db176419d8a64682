"""The dataset store contract (Zarr v3), shared by simgen (writer) and learner (reader).

Layout of one store (one dataset), version 3::

    <store>/                      attrs: schema_version, spec, spec_hash, complete, provenance,
                                         simulation, split, statistics, summary (and added: edits)
      meshes/<mesh_id>/           attrs: name, cell_type, axis (apex/base/reference or null), shape_params
        points (node, xyz) f8     cells (cell, vertex) i4
        surface / epicardium / endocardium / base / electrodes (k,) i4   observed-node index sets
        stim_nodes (site,) i4     stimulation sites of every subject on this mesh
      subjects/<subject_id>/      attrs: mesh_id, tissue, chunk_sites, solver, split, statistics
        a, D (node,) f4           label (node,) i1
        u (site, time, node) f4   sharded along site: one shard = one build task's sites,
                                  one inner chunk = one site (a simulation decodes alone)
        activation (site, node) f4  first crossing of the activation threshold (NaN = never), time units;
                                    sharded as u
        done (chunk,) u1          1 once a chunk's u, activation and moments are written
        moments (chunk, variable, moment) f8   per-chunk count, sum, sum of squares, min, max of u, activation
        fingerprint (chunk,) u8   per chunk: hash of its subject id, chunk index, sites and data (0 = not written)
        coordinates: site (site,) i4 stimulated node ids, times (time,) f8 in time units,
                     time_ms (time,) f8, x / y / z (node,) f8 in mm

Every array carries CF-style ``units`` and ``long_name`` attributes, and a
data array lists the coordinates along its dimensions in ``coordinates``, so
``xarray.open_zarr(store, group="subjects/<id>")`` labels sites, frames and
nodes. Rules: ``done[k]`` is written only after chunk ``k``'s data; readers
must treat a chunk with ``done == 0`` as missing. Every chunk of every array
ends in a CRC32C checksum (version 3). Stores of versions 1 (no coordinates,
moments, units or the attributes of version 2) and 2 (``u`` and ``activation``
unsharded: one chunk per build task; no checksum on mesh, tissue and coordinate
arrays; no fingerprints) are still read, never written: see
:func:`check_schema_version`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from shared.errors import SchemaError
from shared.units import TIME_UNITS

__all__ = [
    "SCHEMA_VERSION",
    "METADATA_VERSION",
    "READABLE_VERSIONS",
    "SHARDED_ARRAYS",
    "ArraySpec",
    "MESH_ARRAYS",
    "FIBRE_ARRAYS",
    "ECG_MESH_ARRAYS",
    "ECG_ARRAYS",
    "MESH_INDEX_SETS",
    "SUBJECT_ARRAYS",
    "MOMENT_VARIABLES",
    "MOMENTS",
    "SchemaWarning",
    "array_attributes",
    "mesh_path",
    "subject_path",
    "check_schema_version",
]

#: Bumped on any change of names, dtypes, dimensions, required attributes or chunk layout below.
#: Version 3 shards :data:`SHARDED_ARRAYS`: one shard per build task, one inner chunk per site; it
#: checksums every array (mesh, tissue and coordinates too) and adds the chunk ``fingerprint``.
SCHEMA_VERSION = 3

#: The version that added units, coordinates, moments, statistics, the split and provenance.
METADATA_VERSION = 2

#: Versions this code reads; it writes :data:`SCHEMA_VERSION` only.
READABLE_VERSIONS = (1, METADATA_VERSION, SCHEMA_VERSION)

#: Result arrays sharded along ``site`` (from version 3): a shard holds one build task's sites, an
#: inner chunk one site, so reading one simulation decodes that simulation only.
SHARDED_ARRAYS = ("u", "activation")

#: What a store of an older readable version lacks (named by the :class:`SchemaWarning`).
_LACKS = {
    1: "the metadata of version 2 (units, coordinates, statistics, canonical split, provenance) "
    "and what version 3 added (sharding, checksums on every array, chunk fingerprints)",
    2: "what version 3 added: sharding (reading one simulation decodes its build task's whole chunk), "
    "checksums on mesh, tissue and coordinate arrays, chunk fingerprints",
}


@dataclass(frozen=True)
class ArraySpec:
    """Dtype, dimension names and CF ``units`` / ``long_name`` of one array.

    ``coordinate``: the array labels its dimensions (xarray shows it as a
    coordinate); ``since``: the schema version that added the array.
    """

    dtype: str
    dims: tuple[str, ...]
    units: str
    long_name: str
    coordinate: bool = False
    since: int = 1


#: Index sets of nodes stored per mesh (observation operators read these).
MESH_INDEX_SETS = ("surface", "epicardium", "endocardium", "base", "electrodes")

MESH_ARRAYS: dict[str, ArraySpec] = {
    "points": ArraySpec("float64", ("node", "xyz"), "mm", "node coordinates"),
    "cells": ArraySpec("int32", ("cell", "vertex"), "1", "node ids of each cell's vertices"),
    "stim_nodes": ArraySpec("int32", ("site",), "1", "stimulated node id of each site"),
    **{
        name: ArraySpec("int32", (f"{name}_node",), "1", f"node ids of the {name} node set") for name in MESH_INDEX_SETS
    },
}

#: Arrays a mesh group holds only where its spec entry gives it fibres (``[meshes.fibres]``): without them
#: the mesh conducts isotropically.
FIBRE_ARRAYS: dict[str, ArraySpec] = {
    "fibre": ArraySpec("float32", ("node", "xyz"), "1", "unit fibre direction at each node"),
    "sheet": ArraySpec("float32", ("node", "xyz"), "1", "unit sheet direction at each node (orthogonal to its fibre)"),
}

#: What a build with ``[output] ecg = true`` adds: per mesh the electrode positions (names in its ``ecg``
#: attribute), per subject each simulation's 12-lead pseudo-ECG (lead names in the mesh's ``ecg`` attribute),
#: sharded as ``u`` is.
ECG_MESH_ARRAYS: dict[str, ArraySpec] = {
    "ecg_electrodes": ArraySpec("float64", ("electrode", "xyz"), "mm", "ECG electrode positions"),
}
ECG_ARRAYS: dict[str, ArraySpec] = {
    "ecg": ArraySpec("float32", ("site", "lead", "time"), "mV", "12-lead pseudo-ECG"),
}

#: Variables and moments of a subject's ``moments`` array (its last two dimensions).
MOMENT_VARIABLES = ("u", "activation")
MOMENTS = ("count", "sum", "sum_sq", "min", "max")

SUBJECT_ARRAYS: dict[str, ArraySpec] = {
    "a": ArraySpec("float32", ("node",), "1", "excitability threshold a of the Aliev-Panfilov model"),
    "D": ArraySpec("float32", ("node",), "1", "diffusivity scale (conductivity = solver diffusivity x D)"),
    "label": ArraySpec("int8", ("node",), "1", "tissue label: 0 healthy, 1 border zone, 2 scar core"),
    "u": ArraySpec(
        "float32", ("site", "time", "node"), "1", "transmembrane potential u, dimensionless (V = 100 u - 80 mV)"
    ),
    "activation": ArraySpec(
        "float32",
        ("site", "node"),
        TIME_UNITS,
        "activation time: first crossing of the activation threshold (NaN = never)",
    ),
    "times": ArraySpec("float64", ("time",), TIME_UNITS, "frame time in model time units", coordinate=True),
    "done": ArraySpec("uint8", ("chunk",), "1", "chunk done flag: 1 once the chunk's data are written"),
    "site": ArraySpec("int32", ("site",), "1", "stimulated node id", coordinate=True, since=2),
    "time_ms": ArraySpec("float64", ("time",), "ms", "frame time", coordinate=True, since=2),
    **{
        axis: ArraySpec("float64", ("node",), "mm", f"node {axis} coordinate", coordinate=True, since=2)
        for axis in "xyz"
    },
    "moments": ArraySpec(
        "float64",
        ("chunk", "variable", "moment"),
        "1",
        "per-chunk count, sum, sum of squares, min and max of the finite values of u "
        "(dimensionless) and activation (model time units)",
        since=2,
    ),
    "fingerprint": ArraySpec(
        "uint64",
        ("chunk",),
        "1",
        "per-chunk content fingerprint: 64-bit BLAKE2b of the subject id, chunk index, site range and the "
        "CRC32C of its u and activation (0 = not written)",
        since=3,
    ),
}


class SchemaWarning(UserWarning):
    """A store of an older schema version is read without what was added since (metadata, sharding)."""


def array_attributes(table: Mapping[str, ArraySpec], name: str) -> dict[str, str]:
    """CF attributes of array ``name`` of ``table``: ``units``, ``long_name`` and, for a
    data array, ``coordinates`` (the coordinate arrays along its dimensions)."""
    spec = table[name]
    attrs = {"units": spec.units, "long_name": spec.long_name}
    aux = [key for key, c in table.items() if c.coordinate and key not in spec.dims and set(c.dims) <= set(spec.dims)]
    if aux and not spec.coordinate:
        attrs["coordinates"] = " ".join(aux)
    return attrs


def mesh_path(mesh_id: str) -> str:
    """Group path of a mesh."""
    return f"meshes/{mesh_id}"


def subject_path(subject_id: str) -> str:
    """Group path of a subject."""
    return f"subjects/{subject_id}"


def check_schema_version(attrs: Mapping[str, Any], where: str = "store", write: bool = False) -> int:
    """The store's schema version, after a check that this code reads it (``write``: writes it).

    Raises :class:`SchemaError` for a store without a version, of an unknown
    version or, with ``write``, of an older one (resuming or editing it needs
    a rebuild). Reading an older store warns (:class:`SchemaWarning`): version 1
    lacks coordinates, units, statistics, the canonical split and provenance;
    versions 1 and 2 store ``u`` and ``activation`` one chunk per build task.
    """
    version = attrs.get("schema_version")
    if version is None:
        hint = f"; its root attributes are restored with `simgen repair {where}`" if "spec" in attrs else ""
        raise SchemaError(f"{where} has no schema_version attribute: not a simgen dataset store{hint}")
    rebuild = f"rebuild it with `simgen build SPEC --store {where} --force` (its spec is the root attribute 'spec')"
    if version not in READABLE_VERSIONS:
        raise SchemaError(
            f"{where} has schema_version {version}, this code reads versions "
            f"{', '.join(map(str, READABLE_VERSIONS))}; {rebuild} or use a matching release"
        )
    if write and version != SCHEMA_VERSION:
        raise SchemaError(
            f"{where} has schema_version {version}, this simgen writes version {SCHEMA_VERSION} only: "
            f"to resume or edit the store, {rebuild}"
        )
    if version != SCHEMA_VERSION:
        warnings.warn(
            f"{where} has schema_version {version}: read without {_LACKS[version]}; {rebuild} to add them",
            SchemaWarning,
            stacklevel=2,
        )
    return version
