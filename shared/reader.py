"""Read-only access to a dataset store through the schema (used by simgen and learner alike).

Every function opens the store lazily and reads only what it returns, so a
reader never holds more than one subject's arrays.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Literal

import numpy as np
import zarr
from numpy.typing import ArrayLike, NDArray
from zarr.errors import ZarrUserWarning

from shared.errors import DamagedData, InputError, SchemaError
from shared.integrity import SubjectReader, read_checked, repair_hint
from shared.location import is_url
from shared.mesh import LongAxis, Mesh
from shared.schema import MESH_INDEX_SETS, check_schema_version, mesh_path, subject_path
from shared.tissue import DEFAULT_SETTING_NAMES, TissueFields
from shared.units import MS_PER_TIME_UNIT

__all__ = [
    "check_store",
    "subject_ids",
    "implied_subject_ids",
    "checked_subject_ids",
    "subject_attrs",
    "done_flags",
    "read_mesh",
    "read_tissue",
    "read_sites",
    "read_index_set",
    "read_statistics",
    "read_split",
    "read_solver_settings",
    "read_integrator",
    "read_ecg",
    "integrator_of",
    "LEGACY_INTEGRATOR",
    "read_times",
    "subject_array",
    "read_rows",
    "read_u",
    "read_activation",
    "SubjectReader",
]


def _has_root_metadata(path: str | Path) -> bool:
    """Whether ``zarr.json`` exists in the store: a folder, or an fsspec URL (``s3://bucket/x.zarr``)."""
    if is_url(path):
        import fsspec

        fs, root = fsspec.url_to_fs(path)
        fs.invalidate_cache(root)  # a listing cached earlier in this process may predate the store
        return fs.exists(f"{root.rstrip('/')}/zarr.json")
    return (Path(path) / "zarr.json").exists()


def check_store(path: str | Path, write: bool = False) -> dict:
    """Root attributes of an existing store (a folder or an fsspec URL) after a schema-version check.

    ``write``: the store is to be written (resumed or edited), which needs the current schema version.
    """
    restore = f"a simgen store is restored with `simgen repair {path} --spec SPEC`"
    if not _has_root_metadata(path):
        raise SchemaError(f"{path} is not a Zarr store (no zarr.json); {restore}")
    try:
        attrs = dict(zarr.open_group(str(path), mode="r").attrs)
    except ValueError as exc:  # not JSON, or not Zarr metadata
        raise SchemaError(f"{path}: its root metadata (zarr.json) is unreadable ({exc}); {restore}") from None
    check_schema_version(attrs, str(path), write=write)
    return attrs


def subject_ids(path: str | Path) -> list[str]:
    """Ids of every subject in the store, sorted (from the live metadata, not the consolidated copy)."""
    root = zarr.open_group(str(path), mode="r", use_consolidated=False)
    return sorted(name for name, _ in root["subjects"].groups())


def implied_subject_ids(attrs: dict) -> list[str] | None:
    """The subject ids the root attributes ``spec`` and ``added`` imply (mesh x tissue setting), in that order.

    ``None`` when the store records no spec. The ids simgen's structure check
    (``simgen verify``) expects: the spec's meshes (random anatomies listed one
    by one) times its settings (``"default"``: the 16 default ones, then the
    custom ones), then each ``add-subject``'s subjects.
    """
    spec = attrs.get("spec")
    if not isinstance(spec, dict):
        return None
    names: list[str] = []
    for name in spec.get("tissue", []):
        names += list(DEFAULT_SETTING_NAMES) if name == "default" else [name]
    names += [table["name"] for table in spec.get("custom_tissue", [])]
    ids = [f"{mesh['id']}-{name}" for mesh in spec.get("meshes", []) for name in dict.fromkeys(names)]
    for entry in attrs.get("added", []):
        ids += list(entry.get("subjects", []))
    return ids


def checked_subject_ids(path: str | Path, attrs: dict | None = None) -> list[str]:
    """:func:`subject_ids`, refusing a store that lacks a subject its spec implies (:func:`implied_subject_ids`).

    ``attrs``: the root attributes, if the caller has them. A reader would
    otherwise leave the subject out silently: the error names it and the
    repair command.
    """
    attrs = dict(zarr.open_group(str(path), mode="r").attrs) if attrs is None else attrs
    try:
        with warnings.catch_warnings():  # a subject folder without zarr.json: named below
            warnings.simplefilter("ignore", ZarrUserWarning)
            found = subject_ids(path)
    except KeyError:  # no subjects group at all
        found = []
    missing = [sid for sid in implied_subject_ids(attrs) or [] if sid not in set(found)]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise DamagedData(
            f"store {path}: subject(s) {shown} implied by its spec are missing (no {subject_path(missing[0])}/zarr.json"
            f"{' ...' if len(missing) > 1 else ''}); {repair_hint(str(path))}"
        )
    return found


def _subject_group(path: str | Path, subject_id: str) -> zarr.Group:
    """The subject's group; :class:`InputError` naming the subject when the store has none."""
    try:
        return zarr.open_group(str(path), path=subject_path(subject_id), mode="r", zarr_format=3)
    except FileNotFoundError:  # zarr's GroupNotFoundError derives from it
        raise InputError(f"unknown subject {subject_id!r} in store {path}") from None
    except ValueError as exc:  # its zarr.json is not JSON
        raise DamagedData(
            f"store {path}: subject {subject_id}: group metadata unreadable ({exc}); {repair_hint(str(path))}"
        ) from None


def subject_attrs(path: str | Path, subject_id: str) -> dict:
    """Attributes of a subject group: ``mesh_id``, ``tissue``, ``chunk_sites`` (and from version 2
    ``solver``, ``split``, ``statistics``)."""
    return dict(_subject_group(path, subject_id).attrs)


def done_flags(path: str | Path, subject_id: str) -> NDArray[np.bool_]:
    """Completion flag of every chunk of a subject; a damaged flag is :class:`~shared.errors.DamagedData`
    naming its chunk, its file and the repair (:class:`~shared.integrity.SubjectReader`)."""
    _subject_group(path, subject_id)  # an unknown subject named as such
    return SubjectReader(path, subject_id).done == 1


def _mesh_group(path: str | Path, mesh_id: str) -> zarr.Group:
    try:
        return zarr.open_group(str(path), path=mesh_path(mesh_id), mode="r")
    except (FileNotFoundError, KeyError, ValueError) as exc:  # gone, or its zarr.json not JSON
        raise DamagedData(f"store {path}: mesh {mesh_id}: group unreadable ({exc}); {repair_hint(str(path))}") from None


def read_mesh(path: str | Path, mesh_id: str) -> Mesh:
    """The mesh as stored (points, cells, node sets, axis, fibres where stored); each array checked by
    :func:`~shared.integrity.read_checked`."""
    g = _mesh_group(path, mesh_id)
    where = f"mesh {mesh_id}"
    axis = g.attrs.get("axis")
    sets = {
        name: read_checked(g, name, str(path), where)
        for name in MESH_INDEX_SETS
        if name != "electrodes" and g[name].shape[0]
    }
    fibres, sheets = (
        read_checked(g, name, str(path), where).astype(np.float64) if name in g else None for name in ("fibre", "sheet")
    )
    return Mesh(
        points=read_checked(g, "points", str(path), where),
        cells=read_checked(g, "cells", str(path), where),
        node_sets=sets,
        name=g.attrs["name"],
        axis=LongAxis(**{k: np.asarray(v) for k, v in axis.items()}) if axis else None,
        fibres=fibres,
        sheets=sheets,
    )


def read_index_set(path: str | Path, mesh_id: str, name: str) -> NDArray[np.int64]:
    """One stored node index set of a mesh (``surface``, ``epicardium``, ``electrodes``...)."""
    if name not in MESH_INDEX_SETS:
        raise SchemaError(f"unknown node set {name!r}; the store has {', '.join(MESH_INDEX_SETS)}")
    return read_checked(_mesh_group(path, mesh_id), name, str(path), f"mesh {mesh_id}").astype(np.int64)


def read_tissue(path: str | Path, subject_id: str) -> TissueFields:
    """The subject's per-node tissue fields."""
    g, where = _subject_group(path, subject_id), f"subject {subject_id}"
    a, D, label = (read_checked(g, name, str(path), where) for name in ("a", "D", "label"))
    return TissueFields(a.astype(float), D.astype(float), label)


def read_sites(path: str | Path, mesh_id: str) -> NDArray[np.int64]:
    """Stimulation node ids of every subject on ``mesh_id``."""
    return read_checked(_mesh_group(path, mesh_id), "stim_nodes", str(path), f"mesh {mesh_id}").astype(np.int64)


def read_statistics(path: str | Path, subject_id: str | None = None) -> dict | None:
    """Normalisation statistics of ``u`` and ``activation`` of one subject, or of the store (``None``).

    ``{"u": {"count", "mean", "std", "min", "max"}, "activation": {...}}`` over the
    finite values; ``None`` while chunks are pending, and in version-1 stores.
    """
    group = zarr.open_group(
        str(path), mode="r", path=subject_path(subject_id) if subject_id else "", use_consolidated=False
    )
    return group.attrs.get("statistics")


def read_split(path: str | Path) -> dict[str, str]:
    """The store's canonical split: subject id -> ``"train"``, ``"validation"`` or ``"test"``.

    Subjects without a ``split`` attribute (every subject of a version-1 store) are left out.
    """
    parts = {sid: subject_attrs(path, sid).get("split") for sid in subject_ids(path)}
    return {sid: part for sid, part in parts.items() if part is not None}


def read_solver_settings(path: str | Path) -> dict:
    """The build spec's ``[solver]`` table: the settings a simulator takes (``dt`` ``None``: chosen per mesh).

    What the solver resolved on a subject's mesh (``dt``, ``stimulus_radius``
    in mm...) is the subject attribute ``solver`` (:func:`subject_attrs`).
    """
    return dict(zarr.open_group(str(path), mode="r").attrs["spec"]["solver"])


#: The integrator that ran on subjects of stores recording none, neither per subject nor in the spec.
LEGACY_INTEGRATOR = "euler"


def integrator_of(solver: dict, spec_solver: dict) -> str:
    """The time integrator that ran on a subject whose ``solver`` attribute is ``solver``, in a store whose
    spec's ``[solver]`` table is ``spec_solver``: its record; stores written before that record ran the spec's
    integrator, :data:`LEGACY_INTEGRATOR` where the spec left it unset."""
    return solver.get("integrator") or spec_solver.get("integrator") or LEGACY_INTEGRATOR


def read_integrator(path: str | Path, subject_id: str) -> str:
    """The time integrator that ran on the subject: ``"euler"``, ``"rkc"`` or ``"imex"`` (:func:`integrator_of`)."""
    return integrator_of(subject_attrs(path, subject_id).get("solver") or {}, read_solver_settings(path))


def read_times(path: str | Path, subject_id: str, unit: Literal["time", "ms"] = "time") -> NDArray[np.float64]:
    """Frame times ``(time,)`` of a subject in model time units (``"time"``) or in ms (``"ms"``)."""
    g, where = _subject_group(path, subject_id), f"subject {subject_id}"
    if unit == "time":
        return read_checked(g, "times", str(path), where)
    if unit == "ms":  # a version-1 store has no time_ms coordinate
        if "time_ms" in g:
            return read_checked(g, "time_ms", str(path), where)
        return read_checked(g, "times", str(path), where) * MS_PER_TIME_UNIT
    raise InputError(f"unknown time unit {unit!r}; choose 'time' (model units) or 'ms'")


def subject_array(path: str | Path, subject_id: str, name: str) -> zarr.Array:
    """Lazy handle on one array of a subject (``u``, ``activation``...): metadata only, until read.

    Keep it to read many rows of one subject (:func:`read_rows`) without
    opening the subject's group each time.
    """
    return _subject_group(path, subject_id)[name]


def read_rows(array: zarr.Array, rows: ArrayLike) -> NDArray:
    """``array[rows]`` along the site axis, decoding only the chunks that hold ``rows``, one chunk at a time.

    Unverified beyond the chunks' checksums: the readers of ``u`` and
    ``activation`` go through :class:`~shared.integrity.SubjectReader`.

    In a sharded store (schema version 3) a chunk is one site's inner chunk, so
    each row decodes alone (4x faster than ``array.oindex[rows]``, measured);
    in an older store a chunk holds a build task's sites, and a chunk-aligned
    slice per chunk measured ~20 % faster than ``oindex`` and bounds the extra
    memory to one chunk.
    """
    rows = np.asarray(rows, dtype=np.int64)
    step = array.chunks[0]
    out = np.empty((rows.size, *array.shape[1:]), dtype=array.dtype)
    chunk_of = rows // step
    for c in np.unique(chunk_of):
        pick = np.flatnonzero(chunk_of == c)
        start = int(c) * step
        block = array[start : min(start + step, array.shape[0])]
        out[pick] = block[rows[pick] - start]
    return out


def read_u(
    path: str | Path, subject_id: str, rows: ArrayLike | None = None, allow_pending: bool = False
) -> NDArray[np.float32]:
    """Potential ``u`` ``(site, time, node)`` of the site rows ``rows`` (default: every site), verified.

    Every chunk read is checked first (:class:`~shared.integrity.SubjectReader`:
    done flag, checksums, content fingerprint, finite values); damaged or
    misplaced data are a :class:`~shared.errors.DamagedData` naming the
    subject, array, site and file. A row of a chunk whose ``done`` flag is 0
    is refused too, unless ``allow_pending`` (then it holds NaN, :func:`done_flags`).
    """
    reader = SubjectReader(path, subject_id, allow_pending=allow_pending)
    return reader.all("u") if rows is None else reader.rows("u", rows)


def read_ecg(path: str | Path, subject_id: str, rows: ArrayLike | None = None) -> tuple[NDArray[np.float32], list[str]]:
    """The stored 12-lead pseudo-ECGs ``(site, lead, time)`` in mV of ``rows`` (default: all) and the lead names,
    in a store built with ``[output] ecg = true``; rows of chunks not yet done are refused (each chunk file
    carries a checksum that a damaged one fails)."""
    reader = SubjectReader(path, subject_id)
    if "ecg" not in reader.group:
        raise InputError(f"store {path}: subject {subject_id} has no ECG (built without [output] ecg = true)")
    rows = np.arange(reader.n_sites) if rows is None else np.asarray(rows, np.int64).ravel()
    pending = sorted({int(r) for r in rows if not reader.done[int(r) // reader.chunk_sites]})
    if pending:
        raise InputError(f"store {path}: subject {subject_id}, sites {pending[:5]} not simulated yet")
    mesh_id = reader.group.attrs["mesh_id"]
    leads = list(zarr.open_group(str(path), path=mesh_path(mesh_id), mode="r").attrs["ecg"]["leads"])
    return reader.group["ecg"].get_orthogonal_selection((rows, slice(None), slice(None))), leads


def read_activation(
    path: str | Path, subject_id: str, rows: ArrayLike | None = None, allow_pending: bool = False
) -> NDArray[np.float32]:
    """Activation times ``(site, node)`` in model time units (NaN: never activated) of ``rows`` (default: all).

    Verified as :func:`read_u` verifies.
    """
    reader = SubjectReader(path, subject_id, allow_pending=allow_pending)
    return reader.all("activation") if rows is None else reader.rows("activation", rows)
