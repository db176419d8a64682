"""Editing a finished (or unfinished) store: add subjects on a new mesh, regenerate chunks.

Both operations take the store lock, check everything they can before
writing, write only what they own and then simulate through
:func:`simgen.store.runner.run_pending`, so their chunks are computed and
written exactly as a build computes and writes them.

* :func:`add_subject` lays out a new mesh group and one subject group per
  tissue setting with the same code as :func:`simgen.store.layout.create_layout`
  (:func:`~simgen.store.layout.write_mesh_group`,
  :func:`~simgen.store.layout.write_subject_groups`), with the store's own
  solver and output settings, and records the addition in the root attribute
  ``added`` (a list of ``{"mesh", "mesh_sha256", "sites", "tissue", "subjects",
  "provenance"}`` dicts). Each new subject gets its canonical split part
  (:mod:`shared.split`); no other subject moves.
  ``spec`` and ``spec_hash`` are left alone, so ``simgen build SPEC`` still
  recognises (and resumes) the store; its resume covers the added subjects
  too, since tasks come from the store layout.
* :func:`regenerate` clears the ``done`` flags of some chunks and rebuilds
  exactly those chunks (data and moments); nothing else in the store is
  rewritten (the root metadata, and the statistics of a subject when they change, apart).

Both end as a build ends (:func:`~simgen.store.runner.run_pending`): the
statistics of the edited subjects and of the store are recomputed from the
chunk moments. Only stores of the current schema version are edited.

A store with consolidated metadata hides groups added after consolidation
from readers that trust it, so :func:`add_subject` re-consolidates right
after writing its layout.
"""

from __future__ import annotations

import dataclasses
import hashlib
import re
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import zarr

from shared.errors import ConfigError, InputError, SchemaError
from shared.schema import subject_path
from shared.tissue import TissueSpec
from simgen.meshes.catalog import GENERATORS, source_file
from simgen.meshes.shipped import is_real
from simgen.store.layout import (
    check_store,
    consolidate_metadata,
    remove_partials,
    spec_dict_of,
    write_mesh_group,
    write_subject_groups,
)
from simgen.store.location import store_location
from simgen.store.lock import StoreLock
from simgen.store.manifest import Plan, Subject, Task, entry_mesh, select_sites, sock_electrodes, validate_plan
from simgen.store.metadata import provenance, recorded_scar_border
from simgen.store.runner import BuildReport, run_pending
from simgen.store.spec import BuildSpec, MeshEntry, SiteSelection, spec_from_mapping
from simgen.store.structure import refuse_damaged
from simgen.tissue.defaults import default_settings

__all__ = ["add_subject", "addition_plan", "regenerate", "store_spec", "added_entries"]

_ID = re.compile(r"[A-Za-z0-9_-]+")

OnStart = Callable[[int, "str | None"], None]
OnDone = Callable[[str], None]


def store_spec(store: str | Path) -> BuildSpec:
    """The build spec a store was created from (root attribute ``spec``), after a check that simgen writes it."""
    attrs = check_store(store, write=True)
    if "spec" not in attrs:
        raise SchemaError(f"{store} has no spec attribute: not a simgen build store")
    return spec_from_mapping(attrs["spec"])


def added_entries(store: str | Path) -> list[dict]:
    """The additions recorded by :func:`add_subject` (root attribute ``added``), oldest first."""
    return list(check_store(store).get("added", []))


def _root(store: str | Path, mode: str = "r") -> zarr.Group:
    # Not through consolidated metadata: it may predate groups added since.
    return zarr.open_group(str(store), mode=mode, use_consolidated=False)


def _groups(root: zarr.Group, name: str) -> set[str]:
    return {key for key, _ in root[name].groups()} if name in root else set()


def _tissue_list(tissue: Sequence[TissueSpec | str]) -> list[TissueSpec]:
    if isinstance(tissue, (str, TissueSpec)):
        tissue = [tissue]
    if not tissue:
        raise ConfigError("add-subject: give at least one tissue setting")
    defaults = {s.name: s for s in default_settings()}
    settings = []
    for item in tissue:
        if isinstance(item, str):
            if item not in defaults:
                raise ConfigError(f"unknown tissue setting {item!r}; use one of {list(defaults)} or a TissueSpec")
            item = defaults[item]
        if not isinstance(item, TissueSpec):
            raise ConfigError(f"tissue settings must be TissueSpec objects or setting names, got {item!r}")
        if not isinstance(item.name, str) or not _ID.fullmatch(item.name):
            raise ConfigError(
                f"tissue setting name {item.name!r} is not a valid identifier: use letters, digits, '_' and '-' only"
            )
        settings.append(item)
    names = [s.name for s in settings]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"duplicate tissue setting names {dup}: each setting may appear once")
    return settings


def _absolute_source(mesh: MeshEntry) -> MeshEntry:
    if mesh.source in GENERATORS or is_real(mesh.source) or Path(mesh.source).is_absolute():
        return mesh
    return dataclasses.replace(mesh, source=str(Path(mesh.source).resolve()))


def _file_sha256(source: str) -> str | None:
    path = source_file(source)
    return None if path is None else hashlib.sha256(path.read_bytes()).hexdigest()


def addition_plan(spec: BuildSpec, mesh: MeshEntry, settings: list[TissueSpec], sites: SiteSelection) -> Plan:
    """The plan of adding ``mesh`` under ``settings`` to a store of ``spec``, its sites chosen by ``sites``.

    Subjects ``f"{mesh.id}-{setting.name}"``; the spec's seed, chunk size and
    sock electrodes. Raises the mesh and site errors of :func:`~simgen.store.manifest.make_plan`.
    """
    m = entry_mesh(mesh)
    site_nodes = select_sites(m, sites, spec.seed, mesh.id)
    electrodes = sock_electrodes(m, spec.output.sock_electrodes)
    subjects = [Subject(f"{mesh.id}-{s.name}", mesh.id, s) for s in settings]
    size = spec.output.chunk_sites
    tasks = [
        Task(s.id, k, a, min(a + size, len(site_nodes)))
        for s in subjects
        for k, a in enumerate(range(0, len(site_nodes), size))
    ]
    return Plan(spec, {mesh.id: m}, {mesh.id: site_nodes}, {mesh.id: electrodes}, subjects, tasks)


def _finish(report: BuildReport, start: float) -> BuildReport:
    report.seconds = time.perf_counter() - start
    return report


def add_subject(
    store: str | Path,
    mesh: MeshEntry,
    tissue: Sequence[TissueSpec | str],
    sites: SiteSelection | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: OnStart | None = None,
    on_done: OnDone | None = None,
) -> BuildReport:
    """Add mesh ``mesh`` under each setting of ``tissue`` to ``store`` and simulate the new subjects.

    The new subjects are ``f"{mesh.id}-{setting.name}"``; they use the store's
    solver and output settings, the store's seed and, unless ``sites`` is
    given, the store's site selection (applied to the new mesh). ``tissue``
    holds :class:`TissueSpec` objects or names of default settings.

    Raises :class:`InputError` (nothing written) when the mesh id or a subject
    id already exists, and the errors of :func:`validate_plan`
    (:class:`~shared.errors.MeshError`, :class:`~shared.errors.TissueError`,
    :class:`~shared.errors.StimulusError`, :class:`~shared.errors.TimeStepError`)
    before anything is written; :class:`~simgen.store.runner.BuildFailed` when
    tasks keep failing (the layout and finished chunks are kept: rerun
    ``simgen build SPEC`` or :func:`regenerate` to finish).
    """
    start = time.perf_counter()
    store = store_location(store, for_workers=True)
    if not isinstance(mesh, MeshEntry):
        raise ConfigError(f"mesh must be a MeshEntry, got {mesh!r}")
    if sites is not None and not isinstance(sites, SiteSelection):
        raise ConfigError(f"sites must be a SiteSelection, got {sites!r}")
    mesh = _absolute_source(mesh)
    settings = _tissue_list(tissue)
    check_store(store, write=True)  # before the lock creates anything
    with StoreLock(store):
        spec = store_spec(store)
        refuse_damaged(store)  # a group left by an interrupted add-subject is extra: `simgen repair` removes it
        root = _root(store)
        new_ids = [f"{mesh.id}-{s.name}" for s in settings]
        if mesh.id in _groups(root, "meshes"):
            raise InputError(f"store {store} already has a mesh {mesh.id!r}: choose another mesh id")
        taken = sorted(set(new_ids) & _groups(root, "subjects"))
        if taken:
            raise InputError(
                f"store {store} already has subject(s) {taken}: choose another mesh id or tissue setting name"
            )
        # Everything that can fail, before anything is written (as validate_plan does for a build).
        selection = sites if sites is not None else spec.sites
        plan = addition_plan(spec, mesh, settings, selection)
        setups = validate_plan(plan, recorded_scar_border(dict(root.attrs)))
        record = {
            "mesh": spec_dict_of(mesh),
            "mesh_sha256": _file_sha256(mesh.source),
            "sites": spec_dict_of(selection),
            "tissue": [spec_dict_of(s) for s in settings],
            "subjects": new_ids,
            "provenance": provenance(),
        }

        remove_partials(store)
        root = _root(store, "r+")
        root.attrs["complete"] = False
        ecg = spec.output.ecg
        write_mesh_group(root, mesh.id, plan.meshes[mesh.id], plan.sites[mesh.id], plan.electrodes[mesh.id], ecg)
        write_subject_groups(root, plan.subjects, plan.meshes, plan.sites, spec.output, spec.solver, setups)
        root.attrs["added"] = [*root.attrs.get("added", []), record]  # the layout is committed
        consolidate_metadata(store)  # readers of consolidated metadata see the new groups
        report = run_pending(store, spec.solver, scheduler, workers, retries, on_start, on_done, subjects=new_ids)
        return _finish(report, start)


def _chunks_to_clear(root: zarr.Group, subjects: list[str], sites: list[int] | None) -> dict[str, list[int]]:
    known = _groups(root, "subjects")
    unknown = [s for s in subjects if s not in known]
    if unknown:
        raise InputError(f"unknown subject(s) {unknown}; the store has {sorted(known)}")
    chunks = {}
    for subject_id in subjects:
        g = root[subject_path(subject_id)]
        n_sites, size = g["u"].shape[0], int(g.attrs["chunk_sites"])
        n_chunks = g["done"].shape[0]
        if sites is None:
            chunks[subject_id] = list(range(n_chunks))
            continue
        bad = [i for i in sites if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < n_sites]
        if bad:
            raise InputError(
                f"site index {bad[0]!r} is out of range for subject {subject_id!r} "
                f"({n_sites} sites, valid indices 0..{n_sites - 1})"
            )
        chunks[subject_id] = sorted({int(i) // size for i in sites})
    return chunks


def regenerate(
    store: str | Path,
    subjects: Sequence[str],
    sites: Sequence[int] | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: OnStart | None = None,
    on_done: OnDone | None = None,
) -> BuildReport:
    """Recompute every chunk of ``subjects`` (or only the chunks holding site indices ``sites``).

    ``sites`` are positions in the subject's site list (``0 .. S-1``, the
    ``site`` axis of ``u``), not node ids; with several subjects they apply to
    each. The chunks' ``done`` flags are cleared, then the chunks are simulated
    and written as in a build; no other chunk is rewritten. Raises
    :class:`InputError` naming an unknown subject or an out-of-range site
    index, before anything is changed.
    """
    start = time.perf_counter()
    store = store_location(store, for_workers=True)
    if isinstance(subjects, str):
        subjects = [subjects]
    subjects = list(dict.fromkeys(subjects))
    if not subjects:
        raise InputError("regenerate: give at least one subject")
    if sites is not None:
        sites = list(sites)
        if not sites:
            raise InputError("regenerate: --site-index is empty; leave it out to regenerate whole subjects")
    check_store(store, write=True)
    with StoreLock(store):
        spec = store_spec(store)
        refuse_damaged(store)
        chunks = _chunks_to_clear(_root(store), subjects, sites)
        remove_partials(store)
        root = _root(store, "r+")
        root.attrs["complete"] = False
        for subject_id, ks in chunks.items():
            done = root[subject_path(subject_id)]["done"]
            for k in ks:
                done[k] = 0
        consolidate_metadata(store)  # in case an interrupted edit left groups unlisted there
        report = run_pending(store, spec.solver, scheduler, workers, retries, on_start, on_done, subjects=subjects)
        return _finish(report, start)
