"""Zarr I/O of a dataset build: layout creation (driver), chunk writes (workers), progress.

The driver creates every group, array and attribute of the store before any
task runs (:func:`create_layout`); a task writes only its own ``u`` and
``activation`` chunk of one subject and then its ``done`` flag, which lives in
a chunk of its own (:func:`write_chunk`). Nothing two tasks write overlaps, so
workers never coordinate, and a resumed build rewrites missing chunks only.
"""

from __future__ import annotations

import json
import warnings
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from numpy.typing import NDArray
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec
from zarr.core.group import GroupMetadata
from zarr.core.metadata import ArrayV3Metadata
from zarr.storage import MemoryStore

from shared.config import to_mapping
from shared.errors import InputError
from shared.mesh import Mesh
from shared.schema import (
    MESH_ARRAYS,
    MESH_INDEX_SETS,
    SCHEMA_VERSION,
    SUBJECT_ARRAYS,
    check_schema_version,
    mesh_path,
    subject_path,
)
from shared.reader import check_store, read_mesh, read_sites, read_tissue, subject_ids
from shared.tissue import TissueFields
from simgen.build import location
from simgen.build.chunk_files import chunk_file, writable_store, write_checksummed
from simgen.build.lock import LOCK_NAME
from simgen.build.manifest import Subject, Task
from simgen.build.spec import OutputSpec
from simgen.solver.simulate import SolverConfig
from simgen.tissue import tissue_fields

__all__ = [
    "create_layout",
    "write_mesh_group",
    "write_subject_groups",
    "remove_partials",
    "write_chunk",
    "subject_ids",
    "chunk_tasks",
    "pending_tasks",
    "read_mesh",
    "read_tissue",
    "read_sites",
    "consolidate",
    "consolidate_metadata",
    "check_store",
    "StoreMismatch",
]

#: Subject groups read or written at once (Zarr's small-file round trips overlap).
IO_THREADS = 8


class StoreMismatch(InputError):
    """An existing store was built from a different spec."""


def _compressors(kind: str, level: int) -> tuple[Any, ...]:
    """Chunk codecs; a CRC32C checksum last, so a corrupted or truncated chunk fails to read."""
    if kind == "blosc":  # lz4 + bitshuffle: fastest to write and smaller than zstd on u (bench/build.py)
        return (BloscCodec(cname="lz4", clevel=level, shuffle="bitshuffle"), Crc32cCodec())
    if kind == "zstd":
        return (ZstdCodec(level=level), Crc32cCodec())
    return (Crc32cCodec(),)


def _array(group: zarr.Group, name: str, spec_table: dict, shape: tuple[int, ...], chunks=None, **kw) -> zarr.Array:
    spec = spec_table[name]
    return group.create_array(
        name, shape=shape, chunks=chunks or shape, dtype=spec.dtype, dimension_names=spec.dims, **kw
    )


def create_layout(
    path: str | Path, plan, spec_dict: dict, spec_hash: str, force: bool = False, fields: dict | None = None
) -> bool:
    """Create the store for ``plan`` unless it exists with the same spec hash.

    ``path`` is a folder or an fsspec URL (:mod:`simgen.build.location`).
    Returns ``True`` when a new layout was written, ``False`` when an existing
    store of the same spec is reused (resume). A store from another spec is
    refused with :class:`StoreMismatch` unless ``force`` (then everything in it
    but the lock is deleted and the store written anew). ``fields``: the
    subjects' tissue fields by id, as :func:`~simgen.build.manifest.validate_plan`
    returns them (else computed here).
    """
    path = location.store_location(path)
    if location.exists(path, "zarr.json"):
        attrs = dict(zarr.open_group(path, mode="r").attrs)
        check_schema_version(attrs, path)
        if attrs.get("spec_hash") == spec_hash:
            remove_partials(path)
            return False
        if not force:
            raise StoreMismatch(
                f"store {path} was built from a different spec (hash {str(attrs.get('spec_hash'))[:12]}..., "
                f"this spec {spec_hash[:12]}...); use a new store path or --force to replace it"
            )
        location.clear(path, keep={LOCK_NAME})  # the lock stays: this build still holds the store
    elif any(name != LOCK_NAME for name in location.entries(path)):
        raise StoreMismatch(f"{path} exists and is not a simgen store; refusing to write into it")
    root = zarr.open_group(path, mode="a", zarr_format=3)
    root.attrs.update({"schema_version": SCHEMA_VERSION, "spec": spec_dict, "spec_hash": spec_hash, "complete": False})
    for mesh_id, mesh in plan.meshes.items():
        write_mesh_group(root, mesh_id, mesh, plan.sites[mesh_id], plan.electrodes[mesh_id])
    n_sites = {mesh_id: len(sites) for mesh_id, sites in plan.sites.items()}
    write_subject_groups(root, plan.subjects, plan.meshes, n_sites, plan.spec.output, plan.spec.solver, fields)
    return True


def remove_partials(path: str | Path) -> None:
    """Delete ``*.partial`` files half-written by a killed writer (the caller holds the store lock)."""
    location.remove_partials(location.store_location(path))


def write_mesh_group(root: zarr.Group, mesh_id: str, mesh: Mesh, sites: NDArray, electrodes: NDArray) -> zarr.Group:
    """Write group ``meshes/<mesh_id>``: geometry, node index sets, stimulation sites and electrodes.

    The one code path for mesh groups, used by :func:`create_layout` and by
    :func:`simgen.build.edit.add_subject`.
    """
    g = root.require_group(mesh_path(mesh_id))
    _write_mesh(g, mesh, sites, electrodes)
    return g


def write_subject_groups(
    root: zarr.Group,
    subjects: list[Subject],
    meshes: dict[str, Mesh],
    n_sites: dict[str, int],
    output: OutputSpec,
    solver: SolverConfig,
    fields: dict[str, TissueFields] | None = None,
) -> None:
    """Write groups ``subjects/<id>``: attributes, tissue fields and the empty result arrays.

    ``u`` and ``activation`` are chunked by ``output.chunk_sites`` sites (NaN until simulated) and
    ``done`` holds one flag per chunk, all 0. ``meshes`` and ``n_sites`` by mesh id;
    ``fields``: the subjects' tissue fields by id where already computed. All
    groups and arrays are created at once (:func:`zarr.create_hierarchy`), then
    the fields written on threads, which is much faster than creating them array by array
    (the layout is part of a build's serial time, docs/performance.md). The one code
    path for subject groups, used by :func:`create_layout` and by
    :func:`simgen.build.edit.add_subject`.
    """
    nodes: dict[str, Any] = {}
    for s in subjects:
        attrs = {"mesh_id": s.mesh_id, "tissue": spec_dict_of(s.tissue), "chunk_sites": output.chunk_sites}
        nodes[subject_path(s.id)] = GroupMetadata(attributes=attrs)
        for name, (shape, chunks) in _subject_shapes(meshes[s.mesh_id].n_nodes, n_sites[s.mesh_id], output,
                                                     solver).items():  # fmt: skip
            nodes[f"{subject_path(s.id)}/{name}"] = _subject_metadata(name, shape, chunks, output.compressor,
                                                                      output.level)  # fmt: skip
    arrays = dict(zarr.create_hierarchy(store=root.store, nodes=nodes))
    times = solver.output_interval * np.arange(1, solver.frames + 1)

    def write_fields(s: Subject) -> None:
        f = (fields or {}).get(s.id)
        f = f if f is not None else tissue_fields(meshes[s.mesh_id], s.tissue)
        for name, values in (("a", f.a), ("D", f.D), ("label", f.label), ("times", times)):
            arrays[f"{subject_path(s.id)}/{name}"][...] = np.asarray(values, SUBJECT_ARRAYS[name].dtype)

    with ThreadPoolExecutor(IO_THREADS) as pool:
        list(pool.map(write_fields, subjects))


def _subject_shapes(
    n_nodes: int, n_sites: int, output: OutputSpec, solver: SolverConfig
) -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """Shape and chunk shape of each array of a subject group."""
    chunk = min(output.chunk_sites, n_sites)
    field = ((n_nodes,), (n_nodes,))
    return {"a": field, "D": field, "label": field,
            "u": ((n_sites, solver.frames, n_nodes), (chunk, solver.frames, n_nodes)),
            "activation": ((n_sites, n_nodes), (chunk, n_nodes)),
            "done": ((-(-n_sites // output.chunk_sites),), (1,)),
            "times": ((solver.frames,), (solver.frames,))}  # fmt: skip


@lru_cache(maxsize=64)
def _subject_metadata(
    name: str, shape: tuple[int, ...], chunks: tuple[int, ...], compressor: str, level: int
) -> ArrayV3Metadata:
    """Zarr metadata of subject array ``name``, as :meth:`zarr.Group.create_array` makes it (in memory)."""
    kw: dict[str, Any] = {}
    if name in ("u", "activation"):
        kw = {"compressors": _compressors(compressor, level), "fill_value": np.nan}
    elif name == "done":  # its own chunk per flag, written by the task that finished it
        kw = {"compressors": _compressors("none", 0), "fill_value": 0}
    return _array(zarr.open_group(MemoryStore(), mode="w"), name, SUBJECT_ARRAYS, shape, chunks, **kw).metadata


def spec_dict_of(obj: Any) -> Any:
    """JSON-able form of a dataclass (tissue specs in subject attributes)."""
    return json.loads(json.dumps(to_mapping(obj)))


def _write_mesh(g: zarr.Group, mesh: Mesh, sites: NDArray, electrodes: NDArray) -> None:
    axis = None
    if mesh.axis is not None:
        axis = {k: np.asarray(getattr(mesh.axis, k), float).tolist() for k in ("apex", "base", "reference")}
    g.attrs.update({"name": mesh.name, "cell_type": mesh.cell_type, "axis": axis})
    _array(g, "points", MESH_ARRAYS, mesh.points.shape)[...] = mesh.points
    _array(g, "cells", MESH_ARRAYS, mesh.cells.shape)[...] = mesh.cells
    _array(g, "stim_nodes", MESH_ARRAYS, (len(sites),))[...] = np.asarray(sites, np.int32)
    sets = {name: mesh.node_sets.get(name, np.zeros(0, np.int32)) for name in MESH_INDEX_SETS}
    sets["electrodes"] = np.asarray(electrodes, np.int32)
    for name, idx in sets.items():
        arr = _array(g, name, MESH_ARRAYS, (len(idx),), (max(len(idx), 1),))
        if len(idx):
            arr[...] = np.asarray(idx, np.int32)


def result_arrays(path: str | Path, subject_id: str) -> tuple[zarr.Array, zarr.Array, zarr.Array]:
    """A subject's ``u``, ``activation`` and ``done`` arrays, opened for writing (a worker keeps them).

    A local store is opened through :class:`~simgen.build.chunk_files.DirectLocalStore`
    (Zarr's files, written with direct I/O: a 29 MB chunk in ~20 ms instead of 75-80 ms
    through the page cache on the measured VM).
    """
    g = zarr.open_group(writable_store(str(path)), path=subject_path(subject_id), mode="r+")
    # a chunk of results is never all fill value (NaN): skip Zarr's full scan for one before each write
    whole = {"write_empty_chunks": True}
    return g["u"].with_config(whole), g["activation"].with_config(whole), g["done"]


def write_chunk(
    path: str | Path,
    subject_id: str,
    chunk: int,
    start: int,
    stop: int,
    u: NDArray,
    activation: NDArray,
    arrays: tuple[zarr.Array, zarr.Array, zarr.Array] | None = None,
) -> None:
    """Worker: write one chunk of sites, then (only then) its completion flag.

    ``arrays``: :func:`result_arrays` of the subject, opened once by a caller
    that writes many chunks (saves four metadata reads per chunk).
    """
    u_array, activation_array, done = arrays or result_arrays(path, subject_id)
    _write_sites(u_array, chunk, start, stop, u)
    _write_sites(activation_array, chunk, start, stop, activation)
    _write_sites(done, chunk, chunk, chunk + 1, np.ones(1, done.dtype))


def _write_sites(array: zarr.Array, chunk: int, start: int, stop: int, values: NDArray) -> None:
    """``array[start:stop] = values``, sites ``[start, stop)`` being chunk ``chunk`` (or its start, at the end).

    When :func:`~simgen.build.chunk_files.chunk_file` allows, the chunk file is
    written here, straight from ``values`` (29 MB for a default chunk of ``u``:
    Zarr's encoding copies it twice, ~10 ms); sites past the array's end get the
    fill value, as Zarr stores them. Anything else goes through Zarr.
    """
    size = array.chunks[0]
    values = np.ascontiguousarray(values, np.dtype(array.dtype).newbyteorder("<"))
    whole = start == chunk * size and stop == min(start + size, array.shape[0])
    file = chunk_file(array, (chunk,) + (0,) * (array.ndim - 1)) if whole else None
    if file is None or array.chunks[1:] != array.shape[1:] or values.shape != (stop - start, *array.shape[1:]):
        array[start:stop] = values
        return
    write_checksummed(file, values, _fill((size - (stop - start), *array.shape[1:]), values.dtype, array.fill_value))


def _fill(shape: tuple[int, ...], dtype: np.dtype, value: Any) -> NDArray | None:
    """A read-only array of ``value`` (kept for the next subject's last chunk), ``None`` when empty."""
    return _filled(shape, dtype.str, np.asarray(value, dtype).tobytes()) if shape[0] else None


@lru_cache(maxsize=2)
def _filled(shape: tuple[int, ...], dtype: str, value: bytes) -> NDArray:  # the value as bytes: NaN != NaN
    fill = np.full(shape, np.frombuffer(value, dtype)[0], dtype)
    fill.flags.writeable = False
    return fill


def chunk_tasks(path: str | Path, subjects: list[str] | None = None) -> dict[Task, bool]:
    """Every chunk of the store (or of ``subjects``) as a task, with its ``done`` flag; subject then chunk order."""
    root = zarr.open_group(str(path), mode="r", use_consolidated=False)

    def chunks(subject_id: str) -> dict[Task, bool]:
        g = root[subject_path(subject_id)]
        n_sites, size = g["u"].shape[0], int(g.attrs["chunk_sites"])
        return {Task(subject_id, k, k * size, min((k + 1) * size, n_sites)): bool(flag)
                for k, flag in enumerate(g["done"][...])}  # fmt: skip

    with ThreadPoolExecutor(IO_THREADS) as pool:
        found = pool.map(chunks, subjects if subjects is not None else subject_ids(path))
        return {task: done for subject in found for task, done in subject.items()}


def pending_tasks(path: str | Path, subjects: list[str] | None = None) -> list[Task]:
    """Chunks not flagged done, in subject then chunk order (all subjects, or ``subjects``)."""
    return [task for task, done in chunk_tasks(path, subjects).items() if not done]


def consolidate_metadata(path: str | Path) -> None:
    """Consolidate the metadata so readers open the store in one read (and see new groups)."""
    with warnings.catch_warnings():  # consolidated metadata is not (yet) part of the v3 spec
        warnings.simplefilter("ignore")
        zarr.consolidate_metadata(str(path))


def consolidate(path: str | Path, complete: bool | None = None) -> None:
    """Mark the store complete when no chunk is pending, then consolidate its metadata.

    ``complete``: whether no chunk is pending, if the caller knows (else read from the store).
    """
    root = zarr.open_group(str(path), mode="r+", use_consolidated=False)
    root.attrs["complete"] = not pending_tasks(path) if complete is None else complete
    consolidate_metadata(path)
