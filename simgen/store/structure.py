"""A store's structure against its recorded spec: what is missing, extra, mis-shaped or corrupted.

A store records the spec it was built from (root attribute ``spec``) and
every ``add-subject`` (``added``). From them follow its meshes (with their
number of sites) and its subjects (one per mesh and tissue setting, with the
mesh and tissue table each), and from those every group, array and attribute
the store holds: each array's shape, dtype, chunks, codecs, fill value,
dimension names and attributes are those a build writes
(:func:`~simgen.store.layout.subject_array_metadata`,
:func:`~simgen.store.layout.mesh_array_metadata`); node and cell counts are
those of the stored mesh arrays, whose contents are checksummed.

:func:`structure_damage` compares the live metadata (not the consolidated
copy) with that and reads the small arrays whole (mesh, tissue fields,
coordinates, done flags), so a checksum failure is named as what it is; it
reads no result chunk. Groups and arrays the recorded spec does not imply are
named as extra; files and folders without Zarr metadata (a user's notes) are
no members: neither damage nor ever removed (:func:`foreign_files`).
Attributes are checked for presence (and ``mesh_id``, ``tissue`` and
``chunk_sites`` for their value), never refused for being extra. A build
resuming a store, ``add-subject`` and ``regenerate`` run it before they
write (:func:`refuse_damaged`); ``simgen repair`` mends what it finds
(:mod:`simgen.store.repair`).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zarr
from numpy.typing import NDArray
from zarr.errors import ZarrUserWarning

from shared.config import from_mapping
from shared.ecg import ECG_ATTRS
from shared.errors import InputError
from shared.integrity import DIGESTS, array_problem, read_failure
from shared.schema import (
    ECG_ARRAYS,
    ECG_MESH_ARRAYS,
    FIBRE_ARRAYS,
    MESH_ARRAYS,
    METADATA_VERSION,
    SCHEMA_VERSION,
    SUBJECT_ARRAYS,
    mesh_path,
    subject_path,
)
from shared.split import canonical_part
from shared.units import MS_PER_TIME_UNIT
from shared.zarr_format import (
    ArrayV3Metadata,
    Store,
    default_buffer_prototype,
    group_with_attrs,
    metadata_file,
    store_of,
    sync,
)
from simgen.store.layout import mesh_array_metadata, spec_dict_of, subject_array_metadata, subject_shapes
from simgen.store.lock import LOCK_NAME
from simgen.store.spec import BuildSpec, SiteSelection, spec_from_mapping

__all__ = [
    "Damage",
    "Recorded",
    "StoreDamaged",
    "recorded_structure",
    "structure_damage",
    "read_done",
    "stored_names",
    "foreign_files",
    "refuse_damaged",
    "GROUP",
    "GROUP_METADATA",
    "ATTRIBUTES",
    "METADATA",
    "CONTENT",
    "FLAG",
    "EXTRA",
]

#: Arrays of a mesh group.
_MESH_NAMES = (*MESH_ARRAYS,)
#: Vertices per cell of each mesh ``cell_type``.
_VERTICES = {"tetra": 4, "triangle": 3}
#: Attributes every group has, by schema version that added them (statistics come with a finished build).
_ROOT_ATTRS = {1: ("schema_version", "spec", "spec_hash", "complete"), 2: ("provenance", "simulation", "split")}
_MESH_ATTRS = {1: ("name", "cell_type", "axis")}
_SUBJECT_ATTRS = {1: ("mesh_id", "tissue", "chunk_sites"), 2: ("solver", "split")}
#: Subject arrays whose content is read whole by the structure check (small, and read by every build task).
_FIELDS = ("a", "D", "label", "times", "time_ms", "site", "x", "y", "z")


class StoreDamaged(InputError):
    """A store's structure disagrees with its recorded spec, or one of its small arrays fails its checksum."""


#: Kinds of :class:`Damage`, from a whole group gone to one done flag (what ``simgen repair`` does with each:
#: :mod:`simgen.store.repair`).
GROUP = "group"  # a group's folder is gone
GROUP_METADATA = "group metadata"  # a group's zarr.json is gone, unreadable or an array's (its members are stored)
ATTRIBUTES = "attributes"  # a group attribute is missing or disagrees with the recorded spec
METADATA = "metadata"  # an array's zarr.json is gone, unreadable or not what the schema expects
CONTENT = "content"  # an array's values: a checksum, a digest, a chunk file gone, coordinates disagreeing
FLAG = "flag"  # one done flag
EXTRA = "extra"  # a member the recorded spec does not imply


@dataclass(frozen=True)
class Damage:
    """One damaged piece of a store.

    ``group``: the group concerned (``""``: the root; ``meshes/<id>``,
    ``subjects/<id>``); ``array``: its member concerned (``None``: the group
    itself); ``chunk``: the one done flag concerned (``None``: the whole array
    or group); ``kind``: one of :data:`GROUP`, :data:`GROUP_METADATA`,
    :data:`ATTRIBUTES`, :data:`METADATA`, :data:`CONTENT`, :data:`FLAG`,
    :data:`EXTRA`.
    """

    group: str
    problem: str
    array: str | None = None
    chunk: int | None = None
    kind: str = CONTENT

    @property
    def path(self) -> str:
        """The path of the damaged group or array in the store."""
        return f"{self.group}/{self.array}".strip("/") if self.array else self.group

    @property
    def where(self) -> str:
        """``store``, ``mesh <id>`` or ``subject <id>``."""
        if "/" not in self.group:
            return "store"
        kind, name = self.group.split("/", 1)
        return f"{'mesh' if kind == 'meshes' else 'subject'} {name}"

    def __str__(self) -> str:
        return f"{self.where}: {self.problem}"


@dataclass(frozen=True)
class Recorded:
    """What a store's recorded spec and additions imply.

    ``sites``: number of sites by mesh id; ``subjects``: mesh id by subject id;
    ``tissue``: the tissue table by subject id; ``added``: the mesh ids added by
    ``add-subject`` (the others are the spec's); ``fibres``: each mesh's fibre rule (``None``: no fibres).
    """

    spec: BuildSpec
    sites: dict[str, int]
    subjects: dict[str, str]
    tissue: dict[str, dict]
    added: frozenset[str] = field(default_factory=frozenset)
    fibres: dict[str, str | None] = field(default_factory=dict)


def _n_sites(selection: SiteSelection) -> int:
    return len(selection.nodes) if selection.nodes else selection.count


def recorded_structure(attrs: dict) -> Recorded:
    """The meshes and subjects the root attributes ``spec`` and ``added`` imply."""
    spec = spec_from_mapping(attrs["spec"])
    settings = {s.name: spec_dict_of(s) for s in spec.settings()}
    sites = {m.id: _n_sites(spec.sites) for m in spec.meshes}
    subjects = {f"{m.id}-{name}": m.id for m in spec.meshes for name in settings}
    tissue = {f"{m.id}-{name}": table for m in spec.meshes for name, table in settings.items()}
    for entry in attrs.get("added", []):
        mesh_id = entry["mesh"]["id"]
        sites[mesh_id] = _n_sites(from_mapping(SiteSelection, entry["sites"]))
        subjects.update(dict.fromkeys(entry["subjects"], mesh_id))
        tissue.update(zip(entry["subjects"], entry["tissue"]))
    added = frozenset(entry["mesh"]["id"] for entry in attrs.get("added", []))
    fibres = {m.id: m.fibres and m.fibres.rule for m in spec.meshes}
    fibres.update(
        {entry["mesh"]["id"]: (entry["mesh"].get("fibres") or {}).get("rule") for entry in attrs.get("added", [])}
    )
    return Recorded(spec, sites, subjects, tissue, added, fibres)


def _required(table: dict[int, tuple[str, ...]], version: int) -> list[str]:
    return [name for since, names in table.items() if since <= version for name in names]


def _metadata_json(arr: zarr.Array | ArrayV3Metadata) -> dict[str, Any]:
    """An array's ``zarr.json`` as stored (NaN fill values as strings, so they compare equal)."""
    metadata = arr.metadata if isinstance(arr, zarr.Array) else arr
    return json.loads(metadata_file(metadata).to_bytes())


def _metadata_problems(arr: zarr.Array, expected: ArrayV3Metadata, version: int) -> list[str]:
    """Keys of ``arr``'s metadata that differ from ``expected`` (all of them in the current version)."""
    found, want = _metadata_json(arr), _metadata_json(expected)
    if version < SCHEMA_VERSION:  # older layouts: shape, dtype, dimensions and (version 2) CF attributes
        keys = ["shape", "data_type", "dimension_names"] + (["attributes"] * (version >= METADATA_VERSION))
    else:
        keys = sorted(set(found) | set(want))
    return [
        f"{arr.basename} has {key} {found.get(key)}, schema expects {want.get(key)}"
        for key in keys
        if found.get(key) != want.get(key)
    ]


def stored_names(root: zarr.Group, path: str) -> set[str]:
    """The names stored directly under ``path`` of ``root``'s store (members, whatever their metadata), but a
    group's own ``zarr.json``, the store lock and half-written ``*.partial`` files."""

    async def names() -> set[str]:
        return {name async for name in root.store.list_dir(path)}

    try:
        found = sync(names())
    except FileNotFoundError:
        return set()
    return {name for name in found if name not in ("zarr.json", LOCK_NAME) and not name.endswith(".partial")}


class _Checker:
    """Collects the damage of one store (see the module docstring)."""

    def __init__(self, store: str, attrs: dict | None = None) -> None:
        if attrs is None:
            self.root = zarr.open_group(store, mode="r", use_consolidated=False)
        else:  # the root attributes a repair will write, whatever the root zarr.json holds now
            self.root = group_with_attrs(store, attrs)
        self.attrs = dict(self.root.attrs)
        self.version = int(self.attrs["schema_version"])
        self.recorded = recorded_structure(self.attrs)
        self.damage: list[Damage] = []
        self.digests: dict[str, bool] = {}  # whether each mesh and subject group records its arrays' digests
        self.meshes_ok: dict[str, dict[str, NDArray]] = {}  # the sound meshes' arrays
        self.mesh_sizes: dict[str, tuple[int, int]] = {}  # nodes and sites of meshes whose metadata are sound

    def add(self, group: str, problem: str, array: str | None = None, chunk: int | None = None, kind=CONTENT) -> None:
        self.damage.append(Damage(group, problem, array, chunk, kind))

    def members(self, path: str) -> tuple[dict[str, Any], dict | None] | None:
        """The members of group ``path`` (``None`` for one whose metadata do not read) and its attributes
        (``None`` when its own metadata do not read, which is named); ``None`` when nothing is stored there."""
        stored = stored_names(self.root, path)
        try:
            group = self.root[path] if path else self.root
        except (KeyError, ValueError):  # no zarr.json, or not JSON
            group = None
        found: dict[str, Any] = {}
        if not isinstance(group, zarr.Group):
            if group is None and not stored:
                self.add(path, f"group missing ({path})", kind=GROUP)
                return None
            what = "missing or unreadable" if group is None else "an array's, not a group's"
            self.add(path, f"group metadata ({path}/zarr.json) {what}", kind=GROUP_METADATA)
            attrs = None
        else:
            attrs = dict(group.attrs)
            with warnings.catch_warnings():  # a member without metadata is found below
                warnings.simplefilter("ignore", ZarrUserWarning)
                try:
                    found = dict(group.members())
                except Exception:  # noqa: BLE001 - a member's unreadable metadata: each opened alone below
                    found = {}
        for name in sorted(stored - set(found)):
            try:
                found[name] = self.root[f"{path}/{name}".strip("/")]
            except (KeyError, ValueError):  # no zarr.json, or not JSON
                found[name] = None
        return found, attrs

    def extras(self, path: str, members: dict, expected: set[str]) -> None:
        """Name the members under ``path`` that are not ``expected``; a file or folder with no ``zarr.json``
        of its own is no member (a user's notes or figures: never damage, never removed)."""
        for name in sorted(set(members) - expected):
            kind = "group" if isinstance(members[name], zarr.Group) else "array"
            where = f"{path}/{name}".strip("/")
            if members[name] is None and not sync(self.root.store.exists(f"{where}/zarr.json")):
                continue
            self.add(path, f"extra {kind} {where} (not implied by the recorded spec)", name, kind=EXTRA)

    def attributes(self, path: str, attrs: dict | None, required: list[str]) -> None:
        for name in required if attrs is not None else []:
            if name not in attrs:
                self.add(path, f"attribute {name} missing", kind=ATTRIBUTES)

    def metadata(self, path: str, members: dict, name: str, expected: ArrayV3Metadata) -> zarr.Array | None:
        """Array ``name`` of group ``path`` if its metadata are ``expected`` (else the damage is named)."""
        arr = members.get(name)
        if not isinstance(arr, zarr.Array):
            if name not in members:
                problem = f"array {name} missing"
            elif arr is None:
                problem = f"metadata of array {name} ({path}/{name}/zarr.json) missing or unreadable"
            else:
                problem = f"{name} is a group, not an array"
            self.add(path, problem, name, kind=METADATA)
            return None
        problems = _metadata_problems(arr, expected, self.version)
        for problem in problems:
            self.add(path, problem, name, kind=METADATA)
        return None if problems else arr

    def array(self, path: str, members: dict, name: str, expected: ArrayV3Metadata, attrs: dict | None):
        """The values of array ``name`` of group ``path`` if its metadata are ``expected`` and its values
        read back as recorded (:func:`~shared.integrity.array_problem`)."""
        arr = self.metadata(path, members, name, expected)
        return None if arr is None else self.read(path, name, arr, attrs)

    def read(self, path: str, name: str, arr: zarr.Array, attrs: dict | None) -> NDArray | None:
        """The values of array ``name`` of group ``path``; ``None`` (and the damage named) when they do not
        decode or differ from the group's recorded digest."""
        values, problem = array_problem(arr, ((attrs or {}).get(DIGESTS) or {}).get(name))
        if problem is not None:
            self.add(path, problem, name)
        return values

    def check(self) -> list[Damage]:
        self.attributes("", self.attrs, _required(_ROOT_ATTRS, self.version))
        top = self.members("")
        if top is None:
            return self.damage
        self.extras("", top[0], {"meshes", "subjects"})
        meshes = self.members("meshes")
        if meshes is not None:
            self.extras("meshes", meshes[0], set(self.recorded.sites))
        for mesh_id in self.recorded.sites:
            self.mesh(mesh_id)
        subjects = self.members("subjects")
        if subjects is not None:
            self.extras("subjects", subjects[0], set(self.recorded.subjects))
        for subject_id in self.recorded.subjects:
            self.subject(subject_id)
        if any(self.digests.values()):  # written by a layout that records them: each group must
            for path in sorted(path for path, recorded in self.digests.items() if not recorded):
                self.add(path, f"attribute {DIGESTS} missing", kind=ATTRIBUTES)
        return self.damage

    def mesh(self, mesh_id: str) -> None:
        path = mesh_path(mesh_id)
        found = self.members(path)
        if found is None:
            return
        members, attrs = found
        if attrs is not None:
            self.digests[path] = DIGESTS in attrs
        shape_params = self.version >= METADATA_VERSION and mesh_id not in self.recorded.added
        self.attributes(path, attrs, _required(_MESH_ATTRS, self.version) + ["shape_params"] * shape_params)
        rule = self.recorded.fibres.get(mesh_id)
        names = {None: _MESH_NAMES, "file": (*_MESH_NAMES, "fibre"), "ldrb": (*_MESH_NAMES, *FIBRE_ARRAYS)}[rule]
        names = (*names, *ECG_MESH_ARRAYS) if self.recorded.spec.output.ecg else names
        self.extras(path, members, {*names, *(("sheet",) if rule == "file" else ())})  # a file's sheets: optional
        names = (*names, "sheet") if rule == "file" and "sheet" in members else names
        before = len(self.damage)
        values, sizes = {}, {}
        cell_type = (attrs or {}).get("cell_type")
        for name in names:
            arr = members.get(name)
            stored = tuple(arr.shape) if isinstance(arr, zarr.Array) and arr.ndim else (0,)
            shape = {
                "ecg_electrodes": (len(ECG_ATTRS["electrodes"]), 3),
                "points": (stored[0], 3),
                "fibre": (sizes.get("points", stored[0]), 3),
                "sheet": (sizes.get("points", stored[0]), 3),
                "cells": (stored[0], _VERTICES.get(cell_type, 4)),
                "stim_nodes": (self.recorded.sites[mesh_id],),
            }.get(name, stored[:1])
            arr = self.metadata(path, members, name, mesh_array_metadata(name, shape))
            if arr is not None:
                sizes[name], values[name] = arr.shape[0], self.read(path, name, arr, attrs)
        if {"points", "stim_nodes"} <= set(sizes):  # the subjects' shapes are known
            self.mesh_sizes[mesh_id] = sizes["points"], sizes["stim_nodes"]
        if len(self.damage) == before:
            self.meshes_ok[mesh_id] = values

    def subject(self, subject_id: str) -> None:
        path = subject_path(subject_id)
        found = self.members(path)
        if found is None:
            return
        members, attrs = found
        if attrs is not None:
            self.digests[path] = DIGESTS in attrs
        before = len(self.damage)
        self.attributes(path, attrs, _required(_SUBJECT_ATTRS, self.version))
        mesh_id, spec = self.recorded.subjects[subject_id], self.recorded.spec
        tissue, chunk_sites = self.recorded.tissue[subject_id], spec.output.chunk_sites
        implied = {"mesh_id": mesh_id, "tissue": tissue, "chunk_sites": chunk_sites}
        for key, value in implied.items():
            if attrs is not None and key in attrs and attrs[key] != value:
                self.add(
                    path, f"attribute {key} is {attrs[key]!r}, the recorded spec implies {value!r}", kind=ATTRIBUTES
                )
        if mesh_id not in self.mesh_sizes:  # shapes follow from the mesh: nothing more to compare against
            return
        names = [name for name, s in SUBJECT_ARRAYS.items() if s.since <= self.version]
        names += list(ECG_ARRAYS) if spec.output.ecg else []
        self.extras(path, members, set(names))
        shapes = subject_shapes(*self.mesh_sizes[mesh_id], spec.output, spec.solver)
        values = {}
        for name in names:  # the fields are read whole; of the result arrays, only the done flags
            expected = subject_array_metadata(name, *shapes[name], spec.output)
            if name in _FIELDS:
                values[name] = self.array(path, members, name, expected, attrs)
            elif (done := self.metadata(path, members, name, expected)) is not None and name == "done":
                for chunk, problem in read_done(done)[1].items():
                    self.add(path, problem, name, chunk, kind=FLAG)
        mesh = self.meshes_ok.get(mesh_id)
        attributes_sound = not any(d.group == path and d.kind == ATTRIBUTES for d in self.damage[before:])
        if attrs is not None and attributes_sound and mesh is not None and self.version >= METADATA_VERSION:
            self.coordinates(path, subject_id, attrs, mesh, values)

    def coordinates(self, path: str, subject_id: str, attrs: dict, mesh: dict, values: dict) -> None:
        """Coordinates that disagree with the mesh and the spec, a wrong split part, missing solver settings."""
        solver = self.recorded.spec.solver
        times = solver.output_interval * np.arange(1, solver.frames + 1)
        expected = {
            "site": mesh["stim_nodes"],
            "times": times,
            "time_ms": times * MS_PER_TIME_UNIT,
            **{axis: mesh["points"][:, i] for i, axis in enumerate("xyz")},
        }
        for name, value in expected.items():
            if (
                values.get(name) is not None
                and values.get("times") is not None
                and not np.array_equal(values[name], value)
            ):
                self.add(path, f"coordinate {name} disagrees with the mesh and times", name)
        if attrs["split"] != canonical_part(subject_id):
            self.add(
                path,
                f"split attribute {attrs['split']!r}, the canonical split assigns {canonical_part(subject_id)!r}",
                kind=ATTRIBUTES,
            )
        if not {"dt", "steps_per_frame", "stimulus_radius"} <= set(attrs["solver"] or {}):
            self.add(path, "solver attribute incomplete", kind=ATTRIBUTES)


def read_done(done: zarr.Array) -> tuple[NDArray[np.bool_], dict[int, str]]:
    """A subject's done flags, and the problem of each flag that does not read back as 0 or 1.

    The flags are read at once; only when that fails, one by one, so that
    each corrupted flag is named with its chunk. An unreadable flag reads as
    not done.
    """
    try:
        flags = np.asarray(done[...])
        problems = {}
    except Exception:  # find the corrupted flag(s)
        flags, problems = np.zeros(done.shape, done.dtype), {}
        for k in range(done.shape[0]):
            try:
                flags[k] = done[k]
            except Exception as exc:
                problems[k] = f"done flag of chunk {k} {read_failure(done, (k,), exc)}"
    for k in np.flatnonzero(flags > 1):
        problems[int(k)] = f"done flag of chunk {int(k)} is {int(flags[k])} (0 or 1 expected)"
    flags = flags == 1
    flags[list(problems)] = False
    return flags, problems


async def _keys(store: Store, prefix: str) -> list[str]:
    return [key async for key in store.list_prefix(prefix)]


def foreign_files(location: str, path: str) -> list[str]:
    """The files at or under ``path`` of store ``location`` that no Zarr metadata there declare (a user's notes,
    figures).

    A ``zarr.json`` is the store's, and so is every file under the chunk folder
    (``c/``, the default chunk key encoding every simgen array has) of an array
    it declares; anything else is foreign, and a removal that would touch it is
    refused (:mod:`simgen.store.repair`).
    """
    store = store_of(location)
    keys = sync(_keys(store, f"{path}/"))
    if not keys:
        return [path] if sync(store.exists(path)) else []  # a plain file
    arrays = [key.removesuffix("zarr.json") for key in keys if key.endswith("/zarr.json") and _is_array(store, key)]
    return sorted(
        key for key in keys if not key.endswith("/zarr.json") and not any(key.startswith(f"{a}c/") for a in arrays)
    )


def _is_array(store: Store, key: str) -> bool:
    """Whether metadata file ``key`` declares an array (an unreadable one is taken for one: its chunks stay owned)."""
    buffer = sync(store.get(key, prototype=default_buffer_prototype()))
    try:
        return json.loads(buffer.to_bytes()).get("node_type") != "group"
    except (AttributeError, ValueError):
        return True


def structure_damage(store: str, attrs: dict | None = None) -> list[Damage]:
    """Every missing, extra, mis-shaped or corrupted piece of ``store`` but the result chunks.

    ``store``: a :func:`~simgen.store.location.store_location` whose schema
    version the caller has checked (:func:`~shared.reader.check_store`);
    ``attrs``: the root attributes to check against instead of the stored ones
    (a repair's, before it writes them).
    """
    return _Checker(store, attrs).check()


def refuse_damaged(store: str) -> None:
    """Raise :class:`StoreDamaged` naming what :func:`structure_damage` finds and the repair command."""
    damage = structure_damage(store)
    if damage:
        shown = "; ".join(map(str, damage[:5])) + (f"; and {len(damage) - 5} more" if len(damage) > 5 else "")
        raise StoreDamaged(
            f"store {store} is damaged ({len(damage)} problem(s)): {shown}. Run `simgen repair {store}` to restore "
            f"it from its recorded spec (`simgen verify {store}` lists every problem)"
        )
