"""Repair of a damaged store from its recorded spec (``simgen repair STORE``).

Everything a store holds follows from its recorded spec and additions (the
meshes, sites and tissue fields are deterministic, and so are the chunks), so
:func:`repair_store`, holding the store lock:

0. restores the root attributes a layout writes that are missing, from the
   recorded spec, or from the spec file given when the root metadata or its
   spec is gone (which must then match the recorded spec hash, if any); the
   provenance restored is this repair's;
1. finds the structural damage (:func:`~simgen.store.structure.structure_damage`)
   and removes the groups and arrays the recorded spec does not imply;
2. writes every missing or damaged mesh group anew, from the spec or the
   recorded ``add-subject`` (a mesh file must still be where it was);
3. lays out every missing or damaged subject group anew, all its chunks pending
   (steps 1-3 repeat while the check finds more: a subject is checked once its
   mesh is sound); a group is removed whole first, whatever its metadata say;
4. marks not done the chunks whose done flag is corrupted and the done chunks
   whose data fail a check of ``simgen verify`` (without recomputation);
5. resumes the build (:func:`~simgen.store.runner.run_pending`): every pending
   chunk is computed and written as a build writes it, then the statistics,
   summary and ``complete`` are set and the metadata consolidated.

Each step plans what it writes (spec, meshes and mesh files, tissue fields,
time steps) before it writes anything, so a repair that cannot be done stops
with the store as it found it. The repaired store is byte-identical to a clean
build of the same spec, but for a restored provenance (its creation date).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import zarr
from zarr.core.sync import sync

from shared.config import from_mapping
from shared.errors import SchemaError
from shared.schema import check_schema_version, mesh_path, subject_path
from simgen.store.edit import addition_plan
from simgen.store.layout import check_store, layout_attrs, remove_partials, write_mesh_group, write_subject_groups
from simgen.store.location import remove, store_location
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
from simgen.store.structure import Damage, Recorded, StoreDamaged, recorded_structure, structure_damage
from simgen.store.verify import verify_store
from simgen.tissue import tissue_spec_from_mapping

__all__ = ["RepairReport", "repair_store"]

#: Rounds of steps 1-3: the meshes, then the subjects the damaged meshes hid, then a final check.
_ROUNDS = 3


@dataclass
class RepairReport:
    """What :func:`repair_store` did: removed pieces, rewritten groups, chunks computed again."""

    store: str
    root: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    meshes: list[str] = field(default_factory=list)
    subjects: list[str] = field(default_factory=list)
    chunks: list[str] = field(default_factory=list)
    build: BuildReport | None = None

    def lines(self) -> list[str]:
        """One line per kind of repair done (none for a sound store)."""
        found = [
            ("root attributes restored", self.root),
            ("removed", self.removed),
            ("mesh groups written anew", self.meshes),
            ("subject groups laid out anew", self.subjects),
            ("chunks marked not done", self.chunks),
        ]
        return [f"{what}: {', '.join(items)}" for what, items in found if items]


def _recorded_plan(recorded: Recorded, attrs: dict, meshes: set[str], subjects: set[str]) -> Plan:
    """The plan of meshes ``meshes`` and of subjects ``subjects`` (their meshes too), from the recorded spec."""
    needed = meshes | {recorded.subjects[s] for s in subjects}
    spec: BuildSpec = recorded.spec
    plans = []
    entries = [m for m in spec.meshes if m.id in needed]
    if entries:
        plans.append(make_plan(replace(spec, meshes=entries)))
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


def _named(damage: list[Damage], kind: str, every: list[str]) -> set[str]:
    """Ids of the ``kind`` groups (``meshes``, ``subjects``) to write anew: damaged ones, all if ``kind`` is."""
    if any(d.group == kind and not d.extra for d in damage):
        return set(every)
    return {d.group.split("/", 1)[1] for d in damage if d.group.startswith(f"{kind}/") and d.chunk is None}


def _root_attrs(store: str) -> dict | None:
    """The root attributes, ``None`` when the root metadata (``zarr.json``) is missing or unreadable."""
    try:
        return dict(zarr.open_group(store, mode="r", use_consolidated=False).attrs)
    except (FileNotFoundError, ValueError):  # no zarr.json, or not JSON
        return None


def _store_spec(store: str, attrs: dict | None, spec_file: Path | None) -> BuildSpec:
    """The spec to restore ``store`` from: its root attribute ``spec``, else ``spec_file`` (which must match
    the recorded ``spec_hash``, if any)."""
    if attrs is not None and "spec" in attrs:
        return spec_from_mapping(attrs["spec"])
    where = "root metadata (zarr.json) is missing or unreadable" if attrs is None else "root attribute spec is missing"
    if spec_file is None:
        raise SchemaError(
            f"store {store}: its {where}, so its spec is unknown; give the spec it was built from: "
            f"`simgen repair {store} --spec SPEC`"
        )
    spec = load_spec(spec_file)
    recorded = (attrs or {}).get("spec_hash")
    if recorded is not None and spec_hash(spec) not in recorded_hashes(attrs or {}):
        raise SchemaError(
            f"{spec_file} is not the spec of store {store} (hash {spec_hash(spec)[:12]}..., "
            f"the store records {str(recorded)[:12]}...)"
        )
    return spec


def _restored_attrs(attrs: dict, spec: BuildSpec) -> tuple[dict, list[str]]:
    """``attrs`` with the root attributes a layout writes (:func:`~simgen.store.layout.layout_attrs`) it lacks,
    in the layout's order (then the others, as they are), and the names of those restored."""
    layout = layout_attrs(spec_to_dict(spec), spec_hash(spec), spec.solver)
    restored = {key: attrs.get(key, value) for key, value in layout.items()}
    return {**restored, **attrs}, sorted(set(layout) - set(attrs))


def _restore_root(store: str, spec_file: Path | None, report: RepairReport) -> None:
    """Step 0: the missing root attributes. Before the root metadata is written, every mesh and subject the
    restored attributes imply is planned and checked (a repair without its root cannot know what it will
    rewrite), and a spec from ``spec_file`` must fit the arrays the store holds."""
    attrs = _root_attrs(store)
    if attrs is not None and "schema_version" in attrs:
        check_schema_version(attrs, store, write=True)
    spec = _store_spec(store, attrs, spec_file)
    restored, missing = _restored_attrs(attrs or {}, spec)
    if not missing:
        return
    recorded = recorded_structure(restored)
    plan = _recorded_plan(recorded, restored, set(recorded.sites), set(recorded.subjects))
    validate_plan(plan, recorded_scar_border(restored))
    if "spec" in missing:
        _check_fits(store, plan, spec_file)
    if attrs is None:
        remove(store, "zarr.json")  # unreadable: written anew
    zarr.open_group(store, mode="a", zarr_format=3, use_consolidated=False).attrs.put(restored)
    report.root += missing


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
            raise SchemaError(
                f"{spec_file} is not the spec of store {store}: {path} has shape {found}, the spec implies {shape}"
            )


def _remove_tree(root: zarr.Group, path: str) -> None:
    """Delete every file under ``path``, whatever its metadata say (a group whose zarr.json is gone still
    holds its arrays, which Zarr then refuses to overwrite)."""
    sync(root.store.delete_dir(path))


def _mend_structure(store: str, damage: list[Damage], report: RepairReport) -> None:
    """Steps 1-3 of the module docstring for one round of ``damage``: planned, then written."""
    root = zarr.open_group(store, mode="r+", use_consolidated=False)
    attrs = dict(root.attrs)
    recorded = recorded_structure(attrs)
    sound = [d for d in damage if not d.extra]
    meshes = _named(sound, "meshes", list(recorded.sites))
    subjects = _named(sound, "subjects", list(recorded.subjects))
    plan = _recorded_plan(recorded, attrs, meshes, subjects)
    setups = validate_plan(plan, recorded_scar_border(attrs))
    for d in damage:
        if d.extra:
            _remove_tree(root, f"{d.group}/{d.array}".strip("/"))
            report.removed.append(f"{d.group}/{d.array}".strip("/"))
    if not meshes and not subjects:
        return
    root.attrs["complete"] = False
    for mesh_id in sorted(meshes):
        _remove_tree(root, mesh_path(mesh_id))
        group = write_mesh_group(root, mesh_id, plan.meshes[mesh_id], plan.sites[mesh_id], plan.electrodes[mesh_id])
        if mesh_id not in recorded.added:  # as the build's layout writes it
            group.attrs["shape_params"] = next(m.shape_params for m in recorded.spec.meshes if m.id == mesh_id)
    for subject_id in sorted(subjects):
        _remove_tree(root, subject_path(subject_id))
    spec = recorded.spec
    write_subject_groups(root, plan.subjects, plan.meshes, plan.sites, spec.output, spec.solver, setups)
    report.meshes += sorted(meshes)
    report.subjects += sorted(subjects)


def _structural(store: str) -> list[Damage]:
    """The damage of groups and arrays (a corrupted done flag is a chunk's, mended by :func:`_mark_chunks`)."""
    return [d for d in structure_damage(store) if d.chunk is None]


def _mark_chunks(store: str, report: RepairReport) -> None:
    """Step 4: corrupted done flags and done chunks whose data fail a check become not done."""
    found = verify_store(store, sample=0)
    flags = {(d.group.split("/", 1)[1], d.chunk) for d in found.damage if d.chunk is not None}
    chunks = sorted(flags | {(ref.subject_id, ref.chunk) for ref in found.damaged_chunks})
    if not chunks:
        return
    root = zarr.open_group(store, mode="r+", use_consolidated=False)
    root.attrs["complete"] = False
    for subject_id, chunk in chunks:
        root[subject_path(subject_id)]["done"][chunk] = 0
        report.chunks.append(f"{subject_id}/{chunk}")


def repair_store(
    store: str | Path,
    spec_file: str | Path | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: Callable[[int, str | None], None] | None = None,
    on_done: Callable[[str], None] | None = None,
) -> RepairReport:
    """Restore ``store`` from its recorded spec (see the module docstring) and finish its build.

    ``spec_file``: the spec the store was built from, needed only when its
    root metadata or recorded spec is gone. Raises :class:`~shared.errors.SchemaError`
    for a store this simgen does not write or whose spec is unknown,
    :class:`StoreDamaged` for damage still found after :data:`_ROUNDS` rounds,
    and :class:`~simgen.store.runner.BuildFailed` when chunks keep failing.
    """
    store = store_location(store, for_workers=True)
    with StoreLock(store):
        report = RepairReport(store)
        _restore_root(store, None if spec_file is None else Path(spec_file), report)
        spec = spec_from_mapping(check_store(store, write=True)["spec"])
        remove_partials(store)
        damage = _structural(store)
        for _ in range(_ROUNDS):
            if not damage:
                break
            _mend_structure(store, damage, report)
            damage = _structural(store)
        if damage:
            raise StoreDamaged(f"store {store}: still damaged after repair: {'; '.join(map(str, damage))}")
        _mark_chunks(store, report)
        report.build = run_pending(store, spec.solver, scheduler, workers, retries, on_start, on_done)
        return report
