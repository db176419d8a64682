"""Repair of a damaged store from its recorded spec (``simgen repair STORE``).

Everything a store holds follows from its recorded spec and additions (the
meshes, sites and tissue fields are deterministic, and so are the chunks), so
:func:`repair_store`, holding the store lock:

1. finds the structural damage (:func:`~simgen.build.structure.structure_damage`)
   and removes the groups and arrays the recorded spec does not imply;
2. writes every missing or damaged mesh group anew, from the spec or the
   recorded ``add-subject`` (a mesh file must still be where it was);
3. lays out every missing or damaged subject group anew, all its chunks pending
   (steps 1-3 repeat while the check finds more: a subject is checked once its
   mesh is sound);
4. marks not done the chunks whose done flag is corrupted and the done chunks
   whose data fail a check of ``simgen verify`` (without recomputation);
5. resumes the build (:func:`~simgen.build.runner.run_pending`): every pending
   chunk is computed and written as a build writes it, then the statistics,
   summary and ``complete`` are set and the metadata consolidated.

The repaired store is byte-identical to a clean build of the same spec.
Damaged root attributes (provenance, creation date) cannot be derived from the
spec: such a store is rebuilt with ``simgen build SPEC --store STORE --force``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import zarr

from shared.config import from_mapping
from shared.schema import mesh_path, subject_path
from simgen.build.edit import addition_plan, store_spec
from simgen.build.location import store_location
from simgen.build.lock import StoreLock
from simgen.build.manifest import Plan, make_plan, validate_plan
from simgen.build.runner import BuildReport, run_pending
from simgen.build.spec import BuildSpec, MeshEntry, SiteSelection
from simgen.build.store import check_store, remove_partials, write_mesh_group, write_subject_groups
from simgen.build.structure import Damage, Recorded, StoreDamaged, recorded_structure, structure_damage
from simgen.build.verify import verify_store
from simgen.tissue import tissue_spec_from_mapping

__all__ = ["RepairReport", "repair_store"]

#: Rounds of steps 1-3: the meshes, then the subjects the damaged meshes hid, then a final check.
_ROUNDS = 3


@dataclass
class RepairReport:
    """What :func:`repair_store` did: removed pieces, rewritten groups, chunks computed again."""

    store: str
    removed: list[str] = field(default_factory=list)
    meshes: list[str] = field(default_factory=list)
    subjects: list[str] = field(default_factory=list)
    chunks: list[str] = field(default_factory=list)
    build: BuildReport | None = None

    def lines(self) -> list[str]:
        """One line per kind of repair done (none for a sound store)."""
        found = [
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


def _mend_structure(store: str, damage: list[Damage], report: RepairReport) -> None:
    """Steps 1-3 of the module docstring for one round of ``damage``."""
    root = zarr.open_group(store, mode="r+", use_consolidated=False)
    unrepairable = [str(d) for d in damage if d.group == "" and not d.extra]
    if unrepairable:
        raise StoreDamaged(
            f"store {store}: {'; '.join(unrepairable)}; the root attributes cannot be restored from the spec: "
            f"rebuild it with `simgen build SPEC --store {store} --force` (its spec is the root attribute 'spec')"
        )
    for d in damage:
        if d.extra:
            del root[f"{d.group}/{d.array}".strip("/")]
            report.removed.append(f"{d.group}/{d.array}".strip("/"))
    attrs = dict(root.attrs)
    recorded = recorded_structure(attrs)
    meshes = _named([d for d in damage if not d.extra], "meshes", list(recorded.sites))
    subjects = _named([d for d in damage if not d.extra], "subjects", list(recorded.subjects))
    if not meshes and not subjects:
        return
    plan = _recorded_plan(recorded, attrs, meshes, subjects)
    root.attrs["complete"] = False
    for mesh_id in sorted(meshes):
        if mesh_path(mesh_id) in root:
            del root[mesh_path(mesh_id)]
        group = write_mesh_group(root, mesh_id, plan.meshes[mesh_id], plan.sites[mesh_id], plan.electrodes[mesh_id])
        if mesh_id not in recorded.added:  # as the build's layout writes it
            group.attrs["shape_params"] = next(m.shape_params for m in recorded.spec.meshes if m.id == mesh_id)
    for subject_id in sorted(subjects):
        if subject_path(subject_id) in root:
            del root[subject_path(subject_id)]
    spec = recorded.spec
    write_subject_groups(root, plan.subjects, plan.meshes, plan.sites, spec.output, spec.solver, validate_plan(plan))
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
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: Callable[[int, str | None], None] | None = None,
    on_done: Callable[[str], None] | None = None,
) -> RepairReport:
    """Restore ``store`` from its recorded spec (see the module docstring) and finish its build.

    Raises :class:`~shared.errors.SchemaError` for a store this simgen does not
    write, :class:`StoreDamaged` for damage it cannot repair (root attributes,
    or damage still found after :data:`_ROUNDS` rounds), and
    :class:`~simgen.build.runner.BuildFailed` when chunks keep failing.
    """
    store = store_location(store, for_workers=True)
    check_store(store, write=True)
    with StoreLock(store):
        spec = store_spec(store)
        remove_partials(store)
        report = RepairReport(store)
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
