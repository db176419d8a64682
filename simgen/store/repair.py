"""Repair of a damaged store from its recorded spec (``simgen repair STORE``), planned first, never destructive.

Everything a store holds but its results follows from its recorded spec and
additions: the meshes, sites, tissue fields, coordinates, every array's and
group's metadata. The results (``u``, ``activation``, their moments and
fingerprints, the done flags) are checked chunk by chunk. So
:func:`repair_store`, holding the store lock:

1. refuses a path that is not a store, and a ``--spec`` that is not the
   store's (unless ``rescope``: the store becomes that spec's, which must keep
   its solver, output and sites, and the meshes the two share);
2. plans the structural repair (:func:`plan_repair`) from the damage
   :func:`~simgen.store.structure.structure_damage` finds, and refuses it,
   with nothing changed, when the plan would delete a member the spec does not
   imply (unless ``remove_extra``) or cannot be made (a mesh file gone);
3. applies the plan: missing root attributes (the provenance as this
   repair's); group metadata written anew, members kept; mesh arrays, tissue
   fields and coordinates written anew from the spec (deterministic); result
   arrays whose metadata are damaged get their metadata back, their chunk
   files kept; a group whose folder is gone is written anew. Steps 2-3 repeat
   while the check finds more (a subject is checked once its mesh's metadata
   read back);
4. plans and applies the chunks: a done chunk whose data fail a check of
   ``simgen verify`` becomes not done; a chunk not flagged done (or whose flag is
   corrupted) whose data pass every check, its content fingerprint included,
   is flagged done (schema version 3);
5. resumes the build (:func:`~simgen.store.runner.run_pending`): the chunks
   not done are computed, then the statistics, summary and ``complete`` are
   set and the metadata consolidated.

Nothing is deleted or computed again that a check did not prove damaged, so
no repair lowers the number of intact simulations. The repaired store is
byte-identical to a clean build of the same spec, but for a restored
provenance (its creation date).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from shared.config import from_mapping
from shared.errors import SchemaError
from shared.integrity import array_digest
from shared.schema import SCHEMA_VERSION, check_schema_version, mesh_path, subject_path
from shared.zarr_format import sync
from simgen.store.edit import addition_plan
from simgen.store.layout import (
    check_store,
    field_values,
    layout_attrs,
    mesh_array_metadata,
    mesh_attrs,
    mesh_values,
    remove_partials,
    subject_array_metadata,
    subject_attrs,
    subject_shapes,
    write_array,
    write_group_metadata,
    write_mesh_group,
    write_subject_groups,
)
from simgen.store.location import entries, remove, store_location
from simgen.store.lock import StoreLock
from simgen.store.manifest import Plan, make_plan, validate_plan
from simgen.store.metadata import recorded_scar_border
from simgen.store.runner import BuildReport, run_pending
from simgen.store.spec import (
    BuildSpec,
    MeshEntry,
    SiteSelection,
    load_spec,
    recorded_hashes,
    spec_from_mapping,
    spec_hash,
    spec_to_dict,
)
from simgen.store.structure import (
    ATTRIBUTES,
    CONTENT,
    EXTRA,
    FLAG,
    GROUP,
    GROUP_METADATA,
    METADATA,
    Damage,
    Recorded,
    StoreDamaged,
    foreign_files,
    read_done,
    recorded_structure,
    structure_damage,
)
from simgen.store.verify import ChunkRef, chunk_problems, verify_store
from simgen.tissue import tissue_spec_from_mapping

__all__ = ["RepairPlan", "RepairRefused", "RepairReport", "plan_repair", "repair_store"]

#: Rounds of steps 2-3: the meshes, then the subjects the damaged meshes hid, then a final check.
_ROUNDS = 3
#: Result arrays: checked chunk by chunk, never written anew whole (their metadata are).
_RESULTS = ("u", "activation", "moments", "fingerprint", "done")


class RepairRefused(SchemaError):
    """A repair that would destroy what it cannot prove damaged, or that cannot be made; nothing was changed."""


#: What each kind of :class:`RepairPlan` change is called in its lines.
_TITLES = {
    "root": "root attributes restored",
    "removed": "removed (not implied by the spec)",
    "groups": "group metadata written anew (members kept)",
    "meshes": "mesh groups written anew",
    "subjects": "subject groups laid out anew",
    "arrays": "arrays written anew from the spec",
    "metadata": "array metadata written anew (chunk files kept)",
    "chunks": "chunks marked not done (computed again)",
    "flags": "chunks flagged done (their data pass every check)",
}


@dataclass
class RepairPlan:
    """What a repair writes, by kind (each a list of store paths or ``subject/chunk``)."""

    root: list[str] = field(default_factory=list)  # root attributes restored
    removed: list[str] = field(default_factory=list)  # members the spec does not imply (remove_extra, rescope)
    groups: list[str] = field(default_factory=list)  # group metadata written anew, members kept
    meshes: list[str] = field(default_factory=list)  # mesh groups written whole (their folder was gone)
    subjects: list[str] = field(default_factory=list)  # subject groups laid out anew (their folder was gone)
    arrays: list[str] = field(default_factory=list)  # mesh arrays, fields and coordinates written from the spec
    metadata: list[str] = field(default_factory=list)  # result arrays' metadata written anew, chunk files kept
    chunks: list[str] = field(default_factory=list)  # done chunks proved damaged: marked not done, computed again
    flags: list[str] = field(default_factory=list)  # chunks whose data pass every check: flagged done

    def lines(self) -> list[str]:
        """One line per kind of change (none for a sound store)."""
        kinds = [f.name for f in fields(RepairPlan) if getattr(self, f.name)]
        return [f"{_TITLES[kind]}: {', '.join(getattr(self, kind))}" for kind in kinds]

    def extend(self, other: RepairPlan) -> None:
        """Add ``other``'s changes to these."""
        for f in fields(RepairPlan):
            getattr(self, f.name).extend(getattr(other, f.name))


@dataclass
class RepairReport(RepairPlan):
    """What :func:`repair_store` did (:class:`RepairPlan`'s kinds, every round) and the build that finished it."""

    store: str = ""
    build: BuildReport | None = None


def _refuse_non_store(store: str, attrs: dict | None) -> None:
    """Refuse a path that holds no store: nothing there, or neither simgen root metadata nor mesh and subject
    groups (a mistyped path, another folder). Nothing is written there, not even the lock."""
    if attrs is not None and ("schema_version" in attrs or "spec" in attrs):
        return
    names = set(entries(store))
    if not names:
        raise SchemaError(f"{store}: no store there (nothing to repair; check the path)")
    if not {"meshes", "subjects"} & names:
        raise SchemaError(
            f"{store} is not a simgen store (no simgen root metadata, no meshes/ or subjects/ folder); "
            "nothing was changed"
        )


def _root_attrs(store: str) -> dict | None:
    """The root attributes, ``None`` when the root metadata (``zarr.json``) is missing or unreadable."""
    try:
        return dict(zarr.open_group(store, mode="r", use_consolidated=False).attrs)
    except (FileNotFoundError, ValueError):  # no zarr.json, or not JSON
        return None


def _refuse_rescope(store: str, spec_file: Path, old: BuildSpec, new: BuildSpec) -> None:
    """Refuse a re-scope that would keep results the new spec does not produce: another solver, output or
    site selection, or a mesh or tissue setting of the same id made differently."""
    for name in ("solver", "output", "sites"):
        if getattr(old, name) != getattr(new, name):
            raise RepairRefused(
                f"{spec_file} has other [{name}] settings than store {store}: its results are not that spec's; "
                "build it into a new store (nothing was changed)"
            )
    before, after = {m.id: m for m in old.meshes}, {m.id: m for m in new.meshes}
    settings = ({t.name: t for t in spec.settings()} for spec in (old, new))
    for kind, (a, b) in {"mesh": (before, after), "tissue setting": tuple(settings)}.items():
        for key in sorted(set(a) & set(b)):
            if a[key] != b[key]:
                raise RepairRefused(
                    f"{spec_file} makes {kind} {key!r} otherwise than store {store} did: its subjects' results "
                    f"are not that spec's; give the changed {kind} a new id (nothing was changed)"
                )


def _restored_attrs(attrs: dict, spec: BuildSpec) -> tuple[dict, list[str]]:
    """``attrs`` with the root attributes a layout writes (:func:`~simgen.store.layout.layout_attrs`) it lacks,
    in the layout's order (then the others, as they are), and the names of those restored."""
    layout = layout_attrs(spec_to_dict(spec), spec_hash(spec), spec.solver)
    restored = {key: attrs.get(key, value) for key, value in layout.items()}
    return {**restored, **attrs}, sorted(set(layout) - set(attrs))


@dataclass
class _Root:
    """The root attributes a repair leaves (``attrs``), those it writes (``changed``) and the members a
    re-scope removes (``dropped``: mesh and subject group paths)."""

    attrs: dict
    changed: list[str]
    dropped: set[str]


def _root(store: str, spec_file: Path | None, rescope: bool) -> _Root:
    """Step 1 and the root attributes (see the module docstring); nothing is written."""
    attrs = _root_attrs(store)
    _refuse_non_store(store, attrs)
    if attrs is not None and "schema_version" in attrs:
        check_schema_version(attrs, store, write=True)
    given = None if spec_file is None else load_spec(spec_file)
    dropped: set[str] = set()
    if attrs is not None and "spec" in attrs:
        if given is not None and spec_hash(given) not in recorded_hashes(attrs):
            if not rescope:
                raise RepairRefused(
                    f"{spec_file} is not the spec of store {store} (hash {spec_hash(given)[:12]}..., the store "
                    f"records {str(attrs.get('spec_hash'))[:12]}...); nothing was changed. `--rescope` makes the "
                    "store that spec's (removing the subjects it does not imply)"
                )
            old = recorded_structure(attrs)
            _refuse_rescope(store, spec_file, old.spec, given)
            attrs = {**attrs, "spec": spec_to_dict(given), "spec_hash": spec_hash(given)}
            new = recorded_structure(attrs)
            dropped = {mesh_path(m) for m in set(old.sites) - set(new.sites)}
            dropped |= {subject_path(s) for s in set(old.subjects) - set(new.subjects)}
            restored, missing = _restored_attrs(attrs, given)
            return _Root(restored, ["spec", "spec_hash"] + missing, dropped)
        spec = spec_from_mapping(attrs["spec"])
    else:
        where = (
            "root metadata (zarr.json) is missing or unreadable" if attrs is None else "root attribute spec is missing"
        )
        if given is None:
            raise SchemaError(
                f"store {store}: its {where}, so its spec is unknown; give the spec it was built from: "
                f"`simgen repair {store} --spec SPEC`"
            )
        recorded = (attrs or {}).get("spec_hash")
        if recorded is not None and spec_hash(given) not in recorded_hashes(attrs or {}):
            raise RepairRefused(
                f"{spec_file} is not the spec of store {store} (hash {spec_hash(given)[:12]}..., "
                f"the store records {str(recorded)[:12]}...); nothing was changed"
            )
        spec = given
    restored, missing = _restored_attrs(attrs or {}, spec)
    if "spec" in missing:  # the spec came from a file: it must fit what the store holds
        structure = recorded_structure(restored)
        plan = _recorded_plan(structure, restored, set(structure.sites), set(structure.subjects))
        validate_plan(plan, recorded_scar_border(restored))
        _check_fits(store, plan, spec_file)
    return _Root(restored, missing, dropped)


def _check_fits(store: str, plan: Plan, spec_file: Path | None) -> None:
    """Refuse a spec file that does not describe the arrays ``store`` holds: the nodes and sites of its meshes,
    the sites, frames and nodes of its subjects' ``u`` (arrays that are gone are not compared)."""
    frames = plan.spec.solver.frames
    shapes = {}
    for mesh_id, mesh in plan.meshes.items():
        shapes[f"{mesh_path(mesh_id)}/points"] = (mesh.n_nodes, 3)
        shapes[f"{mesh_path(mesh_id)}/stim_nodes"] = (len(plan.sites[mesh_id]),)
    for s in plan.subjects:
        shapes[f"{subject_path(s.id)}/u"] = (len(plan.sites[s.mesh_id]), frames, plan.meshes[s.mesh_id].n_nodes)
    for path, shape in shapes.items():
        try:
            found = zarr.open_array(store, path=path, mode="r").shape
        except (FileNotFoundError, ValueError):  # gone or unreadable: written anew
            continue
        if found != shape:
            raise RepairRefused(
                f"{spec_file} is not the spec of store {store}: {path} has shape {found}, the spec implies {shape}"
            )


def _recorded_plan(recorded: Recorded, attrs: dict, meshes: set[str], subjects: set[str]) -> Plan:
    """The plan of meshes ``meshes`` and of subjects ``subjects`` (their meshes too), from the recorded spec."""
    needed = meshes | {recorded.subjects[s] for s in subjects}
    spec: BuildSpec = recorded.spec
    plans = []
    entries_ = [m for m in spec.meshes if m.id in needed]
    if entries_:
        plans.append(make_plan(replace(spec, meshes=entries_)))
    for entry in attrs.get("added", []):
        if entry["mesh"]["id"] in needed:
            settings = [tissue_spec_from_mapping(t) for t in entry["tissue"]]
            mesh = from_mapping(MeshEntry, entry["mesh"])
            plans.append(addition_plan(spec, mesh, settings, from_mapping(SiteSelection, entry["sites"])))
    return Plan(
        spec,
        {k: v for p in plans for k, v in p.meshes.items()},
        {k: v for p in plans for k, v in p.sites.items()},
        {k: v for p in plans for k, v in p.electrodes.items()},
        [s for p in plans for s in p.subjects if s.id in subjects],
        [],
    )


# --- one round of the structural repair ------------------------------------------------------------------


class _Round:
    """The structural repair of one round of ``damage``: planned (:attr:`plan`), then :meth:`apply`."""

    def __init__(self, store: str, root: _Root, damage: list[Damage], remove_extra: bool) -> None:
        self.store, self.attrs, self.damage = store, root.attrs, [d for d in damage if d.kind != FLAG]
        self.recorded = recorded_structure(self.attrs)
        self.plan = RepairPlan(root=list(root.changed))
        extras = [d.path for d in self.damage if d.kind == EXTRA]
        kept = [path for path in extras if path not in root.dropped and not remove_extra]
        if kept:
            raise RepairRefused(
                f"store {store} holds {len(kept)} member(s) its recorded spec does not imply: {', '.join(kept)}; "
                "move them out of the store, or give --remove-extra to delete them (nothing was changed)"
            )
        self.plan.removed = extras
        self._refuse_foreign(extras)
        by_group: dict[str, list[Damage]] = {}
        for d in self.damage:
            if d.kind != EXTRA:
                by_group.setdefault(d.group, []).append(d)
        self.by_group = by_group
        self.plan.groups = [g for g in ("meshes", "subjects") if g in by_group]
        meshes = {g.split("/", 1)[1] for g in by_group if g.startswith("meshes/")}
        subjects = {g.split("/", 1)[1] for g in by_group if g.startswith("subjects/")}
        self.made = _recorded_plan(self.recorded, self.attrs, meshes, subjects)
        self.setups = validate_plan(self.made, recorded_scar_border(self.attrs))
        self.values: dict[str, dict[str, np.ndarray]] = {}
        for mesh_id in sorted(meshes):
            self._plan_group(mesh_path(mesh_id), self._mesh_values(mesh_id), self.plan.meshes)
        for s in sorted(self.made.subjects, key=lambda s: s.id):
            self._plan_group(subject_path(s.id), self._subject_values(s), self.plan.subjects)

    def _refuse_foreign(self, paths: list[str]) -> None:
        """Refuse removing ``paths`` when a file under them is no Zarr member's (nothing was changed)."""
        for path in paths:
            foreign = foreign_files(self.store, path)
            if foreign:
                shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
                raise RepairRefused(
                    f"store {self.store}: removing {path} would delete {len(foreign)} file(s) no Zarr metadata "
                    f"declare: {shown}; move them out of the store (nothing was changed)"
                )

    def _mesh_values(self, mesh_id: str) -> dict[str, np.ndarray]:
        made = self.made
        ecg = made.spec.output.ecg
        return mesh_values(made.meshes[mesh_id], made.sites[mesh_id], made.electrodes[mesh_id], ecg)

    def _subject_values(self, s) -> dict[str, np.ndarray]:
        made = self.made
        return field_values(self.setups[s.id], made.meshes[s.mesh_id], made.sites[s.mesh_id], made.spec.solver)

    def _plan_group(self, path: str, values: dict[str, np.ndarray], whole: list[str]) -> None:
        """Plan group ``path``'s repair; ``values``: its arrays as the spec makes them (compared with those the
        check found sound: a repair by another simgen that makes them otherwise is refused)."""
        self.values[path] = values
        found = self.by_group[path]
        kinds = {d.kind for d in found}
        name = path.split("/", 1)[1]
        if GROUP in kinds:
            whole.append(name)
            return
        if kinds & {GROUP_METADATA, ATTRIBUTES}:
            self.plan.groups.append(path)
        damaged = {d.array for d in found if d.array is not None and d.kind in (METADATA, CONTENT)}
        self._refuse_other_making(path, values, damaged)
        for array in sorted(damaged):
            (self.plan.metadata if array in _RESULTS else self.plan.arrays).append(f"{path}/{array}")

    def _refuse_other_making(self, path: str, values: dict[str, np.ndarray], damaged: set[str]) -> None:
        """Refuse when an array the check found sound differs from what the spec makes now."""
        for array, value in values.items():
            if array in damaged:
                continue
            try:
                stored = zarr.open_array(self.store, path=f"{path}/{array}", mode="r")[...]
            except Exception:  # noqa: BLE001 - unreadable: damaged, named by the check
                continue
            if array_digest(stored) != array_digest(value):
                raise RepairRefused(
                    f"store {self.store}: {path}/{array} as this simgen makes it from the recorded spec differs "
                    "from the stored one, so the store's other arrays cannot be restored from the spec; "
                    "rebuild it with the simgen that built it (nothing was changed)"
                )

    def apply(self) -> None:
        """Write the plan (the root attributes first, then group metadata, then arrays)."""
        plan, store = self.plan, self.store
        if plan.root:
            if _root_attrs(store) is None:
                remove(store, "zarr.json")  # unreadable: written anew
            zarr.open_group(store, mode="a", zarr_format=3, use_consolidated=False).attrs.put(self.attrs)
        root = zarr.open_group(store, mode="r+", use_consolidated=False)
        root.attrs["complete"] = False
        for path in plan.removed:
            sync(root.store.delete_dir(path))
        for path in plan.groups:
            write_group_metadata(root, path, self._group_attrs(root, path))
        for mesh_id in plan.meshes:
            made = self.made
            ecg = made.spec.output.ecg
            write_mesh_group(root, mesh_id, made.meshes[mesh_id], made.sites[mesh_id], made.electrodes[mesh_id], ecg)
            write_group_metadata(root, mesh_path(mesh_id), self._group_attrs(root, mesh_path(mesh_id)))
        subjects = [s for s in self.made.subjects if s.id in plan.subjects]
        if subjects:
            spec, made = self.recorded.spec, self.made
            write_subject_groups(root, subjects, made.meshes, made.sites, spec.output, spec.solver, self.setups)
        for path in plan.arrays + plan.metadata:
            group_path, name = path.rsplit("/", 1)
            group = zarr.open_group(store, path=group_path, mode="r+", use_consolidated=False)
            value = None if name in _RESULTS else self.values[group_path][name]
            if value is not None:
                sync(root.store.delete_dir(path))  # chunk files of another layout go with it
            write_array(group, name, self._array_metadata(group_path, name, value), value)

    def _group_attrs(self, root: zarr.Group, path: str) -> dict[str, Any]:
        """The attributes of group ``path`` as a layout writes them, then those it holds beyond them."""
        try:
            held = dict(root[path].attrs)
        except Exception:  # noqa: BLE001 - metadata missing or unreadable: nothing held
            held = {}
        if path in ("meshes", "subjects"):
            return held
        kind, name = path.split("/", 1)
        if kind == "meshes":
            layout = mesh_attrs(self.made.meshes[name], self.values[path])
            if name not in self.recorded.added:
                layout["shape_params"] = self._spec_mesh(name).shape_params
        else:
            s = next(s for s in self.made.subjects if s.id == name)
            spec = self.recorded.spec
            layout = subject_attrs(s, self.setups[name], spec.output, spec.solver, self.values[path])
        return {**layout, **{key: value for key, value in held.items() if key not in layout}}

    def _spec_mesh(self, mesh_id: str) -> MeshEntry:
        return next(m for m in self.recorded.spec.meshes if m.id == mesh_id)

    def _array_metadata(self, group_path: str, name: str, value: np.ndarray | None):
        kind, group_id = group_path.split("/", 1)
        if kind == "meshes":
            return mesh_array_metadata(name, value.shape)
        s = next(s for s in self.made.subjects if s.id == group_id)
        spec = self.recorded.spec
        shapes = subject_shapes(
            self.made.meshes[s.mesh_id].n_nodes, len(self.made.sites[s.mesh_id]), spec.output, spec.solver
        )
        return subject_array_metadata(name, *shapes[name], spec.output)


# --- the chunks -----------------------------------------------------------------------------------------------


def _chunk_plan(store: str) -> tuple[RepairPlan, dict[tuple[str, int], int]]:
    """Step 4: the done flags to change (``(subject, chunk) -> flag``), planned from every chunk's checks."""
    found = verify_store(store, sample=0)
    damaged = {(ref.subject_id, ref.chunk) for ref in found.damaged_chunks}
    attrs = check_store(store)
    version = int(attrs["schema_version"])
    root = zarr.open_group(store, mode="r", use_consolidated=False)
    plan, flags = RepairPlan(), {}
    for subject_id in recorded_structure(attrs).subjects:
        g = root[subject_path(subject_id)]
        done, unreadable = read_done(g["done"])
        size, n_sites = int(g.attrs["chunk_sites"]), g["u"].shape[0]
        for chunk in range(len(done)):
            key = (subject_id, chunk)
            if done[chunk] and key in damaged:
                flags[key] = 0
            elif not done[chunk]:
                ref = ChunkRef(subject_id, chunk, chunk * size, min((chunk + 1) * size, n_sites))
                if version >= SCHEMA_VERSION and not chunk_problems(g, ref, version):
                    flags[key] = 1
                elif chunk in unreadable:
                    flags[key] = 0
    plan.chunks = [f"{s}/{c}" for (s, c), flag in sorted(flags.items()) if flag == 0]
    plan.flags = [f"{s}/{c}" for (s, c), flag in sorted(flags.items()) if flag == 1]
    return plan, flags


def _apply_flags(store: str, flags: dict[tuple[str, int], int]) -> None:
    if not flags:
        return
    root = zarr.open_group(store, mode="r+", use_consolidated=False)
    root.attrs["complete"] = False
    for (subject_id, chunk), flag in sorted(flags.items()):
        root[subject_path(subject_id)]["done"][chunk] = flag


# --- the repair ------------------------------------------------------------------------------------------------


def plan_repair(
    store: str | Path, spec_file: str | Path | None = None, rescope: bool = False, remove_extra: bool = False
) -> RepairPlan:
    """What :func:`repair_store` would change first (nothing is written): the first round of the structure,
    or, for a sound structure, the chunks. Damage that this round's damage hides (a subject whose mesh
    metadata are gone) is found once that is restored. Raises as :func:`repair_store` refuses."""
    store = store_location(store, for_workers=True)
    root = _root(store, None if spec_file is None else Path(spec_file), rescope)
    first = _Round(store, root, structure_damage(store, root.attrs), remove_extra).plan
    return first if first.lines() or root.changed else _chunk_plan(store)[0]


def repair_store(
    store: str | Path,
    spec_file: str | Path | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: Callable[[int, str | None], None] | None = None,
    on_done: Callable[[str], None] | None = None,
    rescope: bool = False,
    remove_extra: bool = False,
    on_plan: Callable[[list[str]], None] | None = None,
) -> RepairReport:
    """Repair ``store`` (see the module docstring) and finish its build.

    ``spec_file``: the spec the store was built from (needed when its root
    metadata or recorded spec is gone; when given, it must be the store's
    unless ``rescope``). ``remove_extra``: delete members the spec does not
    imply (else refused). ``on_plan``: called with each plan's lines before
    it is applied. Raises :class:`RepairRefused` (nothing changed) for a plan
    that would destroy what no check proved damaged,
    :class:`~shared.errors.SchemaError` for what is not a store this simgen
    writes, :class:`StoreDamaged` for damage still found after
    :data:`_ROUNDS` rounds, and :class:`~simgen.store.runner.BuildFailed` when
    chunks keep failing.
    """
    store = store_location(store, for_workers=True)
    _refuse_non_store(store, _root_attrs(store))  # before the lock, which would write there
    with StoreLock(store):
        report = RepairReport(store=store)
        root = _root(store, None if spec_file is None else Path(spec_file), rescope)
        remove_partials(store)
        for _ in range(_ROUNDS):
            step = _Round(store, root, structure_damage(store, root.attrs), remove_extra)
            if not step.plan.lines():
                break
            if on_plan:
                on_plan(step.plan.lines())
            step.apply()
            report.extend(step.plan)
            root = _Root(root.attrs, [], root.dropped)
        else:
            damage = [d for d in structure_damage(store) if d.kind != FLAG]
            if damage:
                raise StoreDamaged(f"store {store}: still damaged after repair: {'; '.join(map(str, damage))}")
        chunks, flags = _chunk_plan(store)
        if on_plan and chunks.lines():
            on_plan(chunks.lines())
        _apply_flags(store, flags)
        report.extend(chunks)
        spec = spec_from_mapping(check_store(store, write=True)["spec"])
        report.build = run_pending(store, spec.solver, scheduler, workers, retries, on_start, on_done)
        return report
