"""Zarr I/O of a dataset build: layout creation (driver), chunk writes (workers), progress.

The driver creates every group, array and attribute of the store before any
task runs (:func:`create_layout`); a task writes only its own ``u`` and
``activation`` shard of one subject (one inner chunk per site, so that a reader
decodes one simulation alone), its ``moments`` and then its ``done`` flag, each
in a chunk of its own (:func:`write_chunk`). Nothing two tasks write overlaps,
so workers never coordinate, and a resumed build rewrites missing chunks only.
"""

from __future__ import annotations

import asyncio
import json
import logging
import warnings
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
import zarr
from numpy.typing import NDArray
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec
from zarr.storage import MemoryStore

from shared.capture import activated_fraction
from shared.cli import PATH_ERRNOS
from shared.config import to_mapping
from shared.ecg import ECG_ATTRS, LEADS, standard_electrodes
from shared.errors import InputError
from shared.integrity import DIGESTS, array_digest
from shared.mesh import Mesh
from shared.reader import check_store, read_mesh, read_sites, read_tissue, subject_ids
from shared.schema import (
    ECG_ARRAYS,
    ECG_MESH_ARRAYS,
    FIBRE_ARRAYS,
    MESH_ARRAYS,
    MESH_INDEX_SETS,
    MOMENT_VARIABLES,
    MOMENTS,
    SCHEMA_VERSION,
    SHARDED_ARRAYS,
    SUBJECT_ARRAYS,
    SchemaWarning,
    array_attributes,
    mesh_path,
    subject_path,
)
from shared.split import canonical_part, split_rule
from shared.units import MS_PER_TIME_UNIT
from shared.zarr_format import ArrayV3Metadata, GroupMetadata, metadata_file, sync
from simgen.solver.simulate import SolverConfig
from simgen.store import location
from simgen.store.chunk_files import writable_store, write_rows
from simgen.store.fingerprint import chunk_fingerprint
from simgen.store.lock import LOCK_NAME
from simgen.store.manifest import Subject, SubjectSetup, Task, subject_solver, validate_plan
from simgen.store.metadata import provenance, simulation_attrs, solver_attrs
from simgen.store.spec import OutputSpec, recorded_hashes
from simgen.store.stats import chunk_moments, statistics

__all__ = [
    "LayoutState",
    "layout_state",
    "layout_attrs",
    "create_layout",
    "write_mesh_group",
    "write_subject_groups",
    "mesh_values",
    "mesh_attrs",
    "field_values",
    "subject_attrs",
    "write_array",
    "write_group_metadata",
    "subject_array_metadata",
    "mesh_array_metadata",
    "remove_partials",
    "subject_shapes",
    "ResultArrays",
    "result_arrays",
    "write_chunk",
    "subject_ids",
    "chunk_tasks",
    "pending_tasks",
    "read_mesh",
    "read_tissue",
    "read_sites",
    "write_statistics",
    "consolidate",
    "consolidate_metadata",
    "check_store",
    "StoreMismatch",
]

#: Subject groups read or written at once (Zarr's small-file round trips overlap).
IO_THREADS = 8

#: Shard :data:`~shared.schema.SHARDED_ARRAYS` (schema version 3). ``False`` lays them out one chunk
#: per build task, as version 2 did: bench/store_read.py sets it to compare the two layouts.
SHARD_RESULTS = True


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
    """Create array ``name`` of ``spec_table``; checksummed (zstd, CRC32C) unless ``compressors`` says otherwise."""
    spec = spec_table[name]
    kw.setdefault("compressors", _compressors("zstd", 0))  # Zarr's default compressor, then a checksum
    return group.create_array(
        name,
        shape=shape,
        chunks=chunks or shape,
        dtype=spec.dtype,
        dimension_names=spec.dims,
        attributes=array_attributes(spec_table, name),
        **kw,
    )


LayoutState = Literal["new", "resume", "replace"]


def layout_state(path: str, spec_hash: str, force: bool = False) -> LayoutState:
    """What a build of the spec hashed ``spec_hash`` does with the store ``path`` (reads only).

    ``"new"``: nothing there but perhaps the lock; ``"resume"``: a store of this
    spec hash and schema version; ``"replace"`` (only with ``force``): a store
    of another spec or an older schema version. Otherwise raises
    :class:`StoreMismatch`, and always for a folder that is no simgen store.
    """
    if not location.exists(path, "zarr.json"):
        if any(name != LOCK_NAME for name in location.entries(path)):
            raise StoreMismatch(
                f"{path} exists and is not a simgen store (no zarr.json); refusing to write into it (a simgen store "
                f"that lost its zarr.json is restored with `simgen repair {path} --spec SPEC`)"
            )
        return "new"
    with warnings.catch_warnings():  # an older version is refused or replaced below, not read
        warnings.simplefilter("ignore", SchemaWarning)
        attrs = check_store(path)
    version = int(attrs["schema_version"])
    same = spec_hash in recorded_hashes(attrs)
    if same and version == SCHEMA_VERSION:
        return "resume"
    if force:
        return "replace"
    why = (
        f"was built from a different spec (hash {str(attrs.get('spec_hash'))[:12]}..., this spec {spec_hash[:12]}...)"
        if not same
        else f"has schema version {version}, this simgen writes version {SCHEMA_VERSION}"
    )
    raise StoreMismatch(f"store {path} {why}; use a new store path or --force to replace it")


def layout_attrs(spec_dict: dict, spec_hash: str, solver: SolverConfig) -> dict[str, Any]:
    """The root attributes a layout writes: schema version, spec and hash, ``complete``, provenance (now),
    simulation and split rule."""
    return {
        "schema_version": SCHEMA_VERSION,
        "spec": spec_dict,
        "spec_hash": spec_hash,
        "complete": False,
        "provenance": provenance(),
        "simulation": simulation_attrs(solver),
        "split": split_rule(),
    }


def create_layout(
    path: str | Path,
    plan,
    spec_dict: dict,
    spec_hash: str,
    force: bool = False,
    setups: dict[str, SubjectSetup] | None = None,
) -> bool:
    """Create the store for ``plan`` unless it exists with the same spec hash.

    ``path`` is a folder or an fsspec URL (:mod:`simgen.store.location`).
    Returns ``True`` when a new layout was written, ``False`` when an existing
    store of the same spec and schema version is reused (resume). A store
    from another spec or an older schema version is refused with
    :class:`StoreMismatch` unless ``force`` (then everything in it but the
    lock is deleted and the store written anew; :func:`layout_state`). ``setups``: the subjects'
    fields and solver settings by id, as :func:`~simgen.store.manifest.validate_plan`
    returns them (else computed here). The root attributes written here
    (provenance, simulation, split rule) are never rewritten by a resume.
    """
    path = location.store_location(path)
    state = layout_state(path, spec_hash, force)
    if state == "resume":
        remove_partials(path)
        return False
    if state == "replace":
        location.clear(path, keep={LOCK_NAME})  # the lock stays: this build still holds the store
    root = zarr.open_group(path, mode="a", zarr_format=3)
    root.attrs.update(layout_attrs(spec_dict, spec_hash, plan.spec.solver))
    shape_params = {m.id: m.shape_params for m in plan.spec.meshes}
    for mesh_id, mesh in plan.meshes.items():
        group = write_mesh_group(
            root, mesh_id, mesh, plan.sites[mesh_id], plan.electrodes[mesh_id], plan.spec.output.ecg
        )
        group.attrs["shape_params"] = shape_params[mesh_id]  # a sampled anatomy's parameters; None otherwise
    setups = setups if setups is not None else validate_plan(plan)
    write_subject_groups(root, plan.subjects, plan.meshes, plan.sites, plan.spec.output, plan.spec.solver, setups)
    return True


def remove_partials(path: str | Path) -> None:
    """Delete ``*.partial`` files half-written by a killed writer (the caller holds the store lock)."""
    location.remove_partials(location.store_location(path))


def write_mesh_group(
    root: zarr.Group, mesh_id: str, mesh: Mesh, sites: NDArray, electrodes: NDArray, ecg: bool | None = None
) -> zarr.Group:
    """Write group ``meshes/<mesh_id>``: geometry, node index sets, stimulation sites and electrodes (and the
    ECG's with ``ecg``).

    The one code path for mesh groups, used by :func:`create_layout` and by
    :func:`simgen.store.edit.add_subject`.
    """
    g = root.require_group(mesh_path(mesh_id))
    _write_mesh(g, mesh, sites, electrodes, ecg)
    return g


def write_subject_groups(
    root: zarr.Group,
    subjects: list[Subject],
    meshes: dict[str, Mesh],
    sites: dict[str, NDArray],
    output: OutputSpec,
    solver: SolverConfig,
    setups: dict[str, SubjectSetup],
) -> None:
    """Write groups ``subjects/<id>``: attributes, tissue fields, coordinates and the empty result arrays.

    ``u``, ``activation`` and ``moments`` are chunked by ``output.chunk_sites``
    sites (NaN until simulated) and ``done`` holds one flag per chunk, all 0.
    ``meshes`` and ``sites`` (stimulated node ids) by mesh id; ``setups``: the
    subjects' fields and solver settings by id (:func:`~simgen.store.manifest.validate_plan`).
    Attributes: ``mesh_id``, ``tissue``, ``chunk_sites``, the resolved
    ``solver`` settings and the canonical ``split`` part (:mod:`shared.split`).
    All groups and arrays are created at once (:func:`zarr.create_hierarchy`), then
    the fields written on threads, which is much faster than creating them array by array
    (the layout is part of a build's serial time, docs/performance.md). The one code
    path for subject groups, used by :func:`create_layout` and by
    :func:`simgen.store.edit.add_subject`.
    """
    nodes: dict[str, Any] = {}
    values = {s.id: field_values(setups[s.id], meshes[s.mesh_id], sites[s.mesh_id], solver) for s in subjects}
    for s in subjects:
        attrs = subject_attrs(s, setups[s.id], output, solver, values[s.id])
        nodes[subject_path(s.id)] = GroupMetadata(attributes=attrs)
        for name, (shape, chunks) in subject_shapes(
            meshes[s.mesh_id].n_nodes, len(sites[s.mesh_id]), output, solver
        ).items():
            nodes[f"{subject_path(s.id)}/{name}"] = subject_array_metadata(name, shape, chunks, output)
    try:
        arrays = dict(zarr.create_hierarchy(store=root.store, nodes=nodes))
    except OSError:
        _abandon_writes()
        raise

    def write_fields(s: Subject) -> None:
        for name, value in values[s.id].items():
            arrays[f"{subject_path(s.id)}/{name}"][...] = value

    with ThreadPoolExecutor(IO_THREADS) as pool:
        list(pool.map(write_fields, subjects))


def field_values(setup: SubjectSetup, mesh: Mesh, sites: NDArray, solver: SolverConfig) -> dict[str, NDArray]:
    """A subject's tissue fields and coordinates, in the stored dtypes (what a layout writes)."""
    f, points = setup.fields, mesh.points
    times = solver.output_interval * np.arange(1, solver.frames + 1)
    values = {
        "a": f.a,
        "D": f.D,
        "label": f.label,
        "times": times,
        "time_ms": times * MS_PER_TIME_UNIT,
        "site": sites,
        "x": points[:, 0],
        "y": points[:, 1],
        "z": points[:, 2],
    }
    return {name: np.asarray(value, SUBJECT_ARRAYS[name].dtype) for name, value in values.items()}


def subject_attrs(
    s: Subject, setup: SubjectSetup, output: OutputSpec, solver: SolverConfig, values: dict[str, NDArray]
) -> dict[str, Any]:
    """The attributes of a subject group as a layout writes them (``values``: :func:`field_values`)."""
    return {
        "mesh_id": s.mesh_id,
        "tissue": spec_dict_of(s.tissue),
        "chunk_sites": output.chunk_sites,
        "solver": solver_attrs(setup, subject_solver(solver, s.tissue), s.tissue.apd_scale),
        "split": canonical_part(s.id),
        DIGESTS: {name: array_digest(value) for name, value in values.items()},
    }


class _AbandonedWrite(logging.Filter):
    """Drops asyncio's "Task exception was never retrieved" report of a write the file system refused."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (isinstance(exc, OSError) and exc.errno in PATH_ERRNOS and "never retrieved" in record.getMessage())


async def _settle_abandoned_writes() -> None:
    """Wait for the writes still in flight on zarr's event loop and take their errors."""
    others = asyncio.all_tasks() - {asyncio.current_task()}
    await asyncio.gather(*others, return_exceptions=True)


def _abandon_writes() -> None:
    """Silence the writes :func:`zarr.create_hierarchy` abandoned after the first one the file system refused.

    It writes a hierarchy's metadata files concurrently and raises the first
    failure (a full disk: no space or no inodes). The writes already failed
    would each print a traceback when collected, those still in flight would
    fail the same way (or at exit, on a closed executor): they are awaited
    here and their reports dropped, so the first failure is the one reported.
    """
    logger = logging.getLogger("asyncio")
    if not any(isinstance(f, _AbandonedWrite) for f in logger.filters):
        logger.addFilter(_AbandonedWrite())
    sync(_settle_abandoned_writes())


def subject_shapes(
    n_nodes: int, n_sites: int, output: OutputSpec, solver: SolverConfig
) -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """Shape and chunk shape of each array of a subject group (for ``u`` and ``activation``, the shard shape)."""
    chunk, n_chunks = min(output.chunk_sites, n_sites), -(-n_sites // output.chunk_sites)
    field, frames = ((n_nodes,), (n_nodes,)), ((solver.frames,), (solver.frames,))
    moments = (len(MOMENT_VARIABLES), len(MOMENTS))
    return {
        "a": field,
        "D": field,
        "label": field,
        "x": field,
        "y": field,
        "z": field,
        "u": ((n_sites, solver.frames, n_nodes), (chunk, solver.frames, n_nodes)),
        "activation": ((n_sites, n_nodes), (chunk, n_nodes)),
        "done": ((n_chunks,), (1,)),
        "moments": ((n_chunks, *moments), (1, *moments)),
        "fingerprint": ((n_chunks,), (1,)),
        "times": frames,
        "time_ms": frames,
        "site": ((n_sites,), (n_sites,)),
        **({"ecg": ((n_sites, len(LEADS), solver.frames), (chunk, len(LEADS), solver.frames))} if output.ecg else {}),
    }


@lru_cache(maxsize=64)
def _subject_metadata(
    name: str, shape: tuple[int, ...], chunks: tuple[int, ...], compressor: str, level: int, sharded: bool
) -> ArrayV3Metadata:
    """Zarr metadata of subject array ``name``, as :meth:`zarr.Group.create_array` makes it (in memory).

    ``sharded``: a result array's ``chunks`` are shards of inner chunks of one site.
    """
    kw: dict[str, Any] = {}
    if name in (*SHARDED_ARRAYS, *ECG_ARRAYS):
        kw = {"compressors": _compressors(compressor, level), "fill_value": np.nan}
        if sharded:
            chunks, kw["shards"] = (1, *chunks[1:]), chunks
    elif name in ("done", "moments", "fingerprint"):  # a chunk of its own per task, written by that task
        kw = {"compressors": _compressors("none", 0), "fill_value": np.nan if name == "moments" else 0}
    table = {**SUBJECT_ARRAYS, **ECG_ARRAYS}
    return _array(zarr.open_group(MemoryStore(), mode="w"), name, table, shape, chunks, **kw).metadata


def subject_array_metadata(
    name: str, shape: tuple[int, ...], chunks: tuple[int, ...], output: OutputSpec
) -> ArrayV3Metadata:
    """Zarr metadata of subject array ``name`` as a build with ``output`` settings writes it."""
    return _subject_metadata(name, shape, chunks, output.compressor, output.level, SHARD_RESULTS)


def _mesh_chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    """Chunk shape of a mesh array: the whole array (one element for an empty node set)."""
    return (max(shape[0], 1), *shape[1:])


def mesh_array_metadata(name: str, shape: tuple[int, ...]) -> ArrayV3Metadata:
    """Zarr metadata of mesh array ``name`` of ``shape`` as :func:`write_mesh_group` writes it."""
    specs = {**MESH_ARRAYS, **FIBRE_ARRAYS, **ECG_MESH_ARRAYS}
    return _array(zarr.open_group(MemoryStore(), mode="w"), name, specs, shape, _mesh_chunks(shape)).metadata


def spec_dict_of(obj: Any) -> Any:
    """JSON-able form of a dataclass (tissue specs in subject attributes)."""
    return json.loads(json.dumps(to_mapping(obj)))


def mesh_values(mesh: Mesh, sites: NDArray, electrodes: NDArray, ecg: bool | None = None) -> dict[str, NDArray]:
    """The arrays of a mesh group, in the stored dtypes (``fibre`` where the mesh has fibres, ``ecg_electrodes``
    with ``ecg``: :func:`~shared.ecg.standard_electrodes`)."""
    sets = {name: mesh.node_sets.get(name, np.zeros(0, np.int32)) for name in MESH_INDEX_SETS}
    values = {"points": mesh.points, "cells": mesh.cells, "stim_nodes": sites, **sets, "electrodes": electrodes}
    if mesh.fibres is not None:
        values["fibre"] = mesh.fibres
    if mesh.sheets is not None:
        values["sheet"] = mesh.sheets
    if ecg:
        values["ecg_electrodes"] = standard_electrodes(mesh).positions
    specs = {**MESH_ARRAYS, **FIBRE_ARRAYS, **ECG_MESH_ARRAYS}
    return {name: np.asarray(value, specs[name].dtype) for name, value in values.items()}


def mesh_attrs(mesh: Mesh, values: dict[str, NDArray]) -> dict[str, Any]:
    """The attributes of a mesh group as a layout writes them: name, cell type, long axis, digests."""
    axis = None
    if mesh.axis is not None:
        axis = {k: np.asarray(getattr(mesh.axis, k), float).tolist() for k in ("apex", "base", "reference")}
    digests = {name: array_digest(value) for name, value in values.items()}
    attrs = {"name": mesh.name, "cell_type": mesh.cell_type, "axis": axis, DIGESTS: digests}
    return attrs if "ecg_electrodes" not in values else {**attrs, "ecg": ECG_ATTRS}


def write_array(group: zarr.Group, name: str, metadata: ArrayV3Metadata, value: NDArray | None) -> None:
    """Create array ``name`` of ``group`` from ``metadata`` (Zarr's ``zarr.json``, as a layout makes it) and,
    unless ``value`` is ``None``, write its values; chunk files already stored are kept (or overwritten)."""
    sync(group.store.set(f"{group.path}/{name}/zarr.json".lstrip("/"), metadata_file(metadata)))
    if value is not None and value.size:
        zarr.open_array(group.store, path=f"{group.path}/{name}".lstrip("/"), mode="r+")[...] = value


def write_group_metadata(root: zarr.Group, path: str, attrs: dict[str, Any]) -> None:
    """Write the ``zarr.json`` of group ``path`` with ``attrs`` (its members are kept)."""
    sync(root.store.set(f"{path}/zarr.json", metadata_file(GroupMetadata(attributes=attrs))))


def _write_mesh(g: zarr.Group, mesh: Mesh, sites: NDArray, electrodes: NDArray, ecg: bool | None) -> None:
    values = mesh_values(mesh, sites, electrodes, ecg)
    g.attrs.update(mesh_attrs(mesh, values))
    for name, value in values.items():
        write_array(g, name, mesh_array_metadata(name, value.shape), value)


class ResultArrays(NamedTuple):
    """The arrays a task writes, in the order it writes them (``ecg`` only in a store that keeps ECGs)."""

    u: zarr.Array
    activation: zarr.Array
    moments: zarr.Array
    fingerprint: zarr.Array
    done: zarr.Array
    ecg: zarr.Array | None = None


def result_arrays(path: str | Path, subject_id: str) -> ResultArrays:
    """A subject's :class:`ResultArrays`, opened for writing (a worker keeps them).

    A local store is opened through :class:`~simgen.store.chunk_files.DirectLocalStore`
    (Zarr's files, written with direct I/O: a 29 MB shard in ~20 ms instead of 75-80 ms
    through the page cache on the measured VM).
    """
    g = zarr.open_group(writable_store(str(path)), path=subject_path(subject_id), mode="r+")
    # a site's results are never all fill value (NaN): skip Zarr's scan for one before each write
    whole = {"write_empty_chunks": True}
    u, activation = g["u"].with_config(whole), g["activation"].with_config(whole)
    ecg = g["ecg"].with_config(whole) if "ecg" in g else None
    return ResultArrays(u, activation, g["moments"], g["fingerprint"], g["done"], ecg)


def write_chunk(
    path: str | Path,
    subject_id: str,
    chunk: int,
    start: int,
    stop: int,
    u: NDArray,
    activation: NDArray,
    arrays: ResultArrays | None = None,
    ecg: NDArray | None = None,
) -> None:
    """Worker: write one chunk of sites (and their ``ecg`` in a store that keeps ECGs), its moments and
    fingerprint, then (only then) its completion flag.

    ``arrays``: :func:`result_arrays` of the subject, opened once by a caller
    that writes many chunks (saves five metadata reads per chunk).
    """
    arrays = arrays or result_arrays(path, subject_id)
    _write_rows(arrays.u, start, u)
    _write_rows(arrays.activation, start, activation)
    if arrays.ecg is not None:
        _write_rows(arrays.ecg, start, ecg)
    _write_rows(arrays.moments, chunk, chunk_moments(u, activation)[None])
    fingerprint = chunk_fingerprint(subject_id, chunk, start, stop, u, activation)
    _write_rows(arrays.fingerprint, chunk, np.array([fingerprint], arrays.fingerprint.dtype))
    _write_rows(arrays.done, chunk, np.ones(1, arrays.done.dtype))


def _write_rows(array: zarr.Array, start: int, values: NDArray) -> None:
    """``array[start:start + len(values)] = values``: the file written straight from ``values`` where
    :func:`~simgen.store.chunk_files.write_rows` can (29 MB for a default shard of ``u``: Zarr's
    encoding copies it twice, ~10 ms), else through Zarr."""
    if not write_rows(array, start, values):
        array[start : start + len(values)] = values


def chunk_tasks(path: str | Path, subjects: list[str] | None = None) -> dict[Task, bool]:
    """Every chunk of the store (or of ``subjects``) as a task, with its ``done`` flag; subject then chunk order."""
    root = zarr.open_group(str(path), mode="r", use_consolidated=False)

    def chunks(subject_id: str) -> dict[Task, bool]:
        g = root[subject_path(subject_id)]
        n_sites, size = g["u"].shape[0], int(g.attrs["chunk_sites"])
        return {
            Task(subject_id, k, k * size, min((k + 1) * size, n_sites)): bool(flag)
            for k, flag in enumerate(g["done"][...])
        }

    with ThreadPoolExecutor(IO_THREADS) as pool:
        found = pool.map(chunks, subjects if subjects is not None else subject_ids(path))
        return {task: done for subject in found for task, done in subject.items()}


def pending_tasks(path: str | Path, subjects: list[str] | None = None) -> list[Task]:
    """Chunks not flagged done, in subject then chunk order (all subjects, or ``subjects``)."""
    return [task for task, done in chunk_tasks(path, subjects).items() if not done]


def write_statistics(path: str | Path, subjects: list[str] | None = None) -> dict | None:
    """Set the ``statistics`` and ``capture`` attributes of ``subjects`` (default: all); return the store's statistics.

    ``statistics`` come from the subjects' chunk moments (:mod:`simgen.store.stats`);
    ``capture`` is ``{"activated_fraction": [...]}``, the share of the nodes
    each site's simulation activates, from which readers tell the sites that
    start no wave (:mod:`shared.capture`). A subject with a pending chunk gets
    ``None`` for both, and so does the store's statistics while any subject has
    one. An attribute is written only when it changes: other subjects' metadata
    stay untouched.
    """
    root = zarr.open_group(str(path), mode="r+", use_consolidated=False)
    ids = subject_ids(path)

    def done_moments(subject_id: str) -> NDArray | None:
        g = root[subject_path(subject_id)]
        return g["moments"][...] if g["done"][...].all() else None

    def capture(subject_id: str) -> dict | None:
        if moments[subject_id] is None:
            return None
        fraction = activated_fraction(root[subject_path(subject_id)]["activation"][...])
        return {"activated_fraction": [round(float(f), 4) for f in fraction]}

    with ThreadPoolExecutor(IO_THREADS) as pool:
        moments = dict(zip(ids, pool.map(done_moments, ids)))
        chosen = ids if subjects is None else subjects
        captures = dict(zip(chosen, pool.map(capture, chosen)))
    for subject_id in chosen:
        attrs = root[subject_path(subject_id)].attrs
        value = None if moments[subject_id] is None else statistics(moments[subject_id])
        for name, new in (("statistics", value), ("capture", captures[subject_id])):
            if name not in attrs or attrs[name] != new:
                attrs[name] = new
    if any(m is None for m in moments.values()):
        return None
    return statistics(np.concatenate(list(moments.values())))


def consolidate_metadata(path: str | Path) -> None:
    """Consolidate the metadata so readers open the store in one read (and see new groups)."""
    with warnings.catch_warnings():  # consolidated metadata is not (yet) part of the v3 spec
        warnings.simplefilter("ignore")
        zarr.consolidate_metadata(str(path))


def consolidate(path: str | Path, complete: bool | None = None, attrs: dict | None = None) -> None:
    """Set root ``attrs`` and mark the store complete when no chunk is pending, then consolidate its metadata.

    ``complete``: whether no chunk is pending, if the caller knows (else read from the store).
    """
    root = zarr.open_group(str(path), mode="r+", use_consolidated=False)
    root.attrs.update({**(attrs or {}), "complete": not pending_tasks(path) if complete is None else complete})
    consolidate_metadata(path)
