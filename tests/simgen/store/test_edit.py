"""Editing stores: add a subject on a new mesh file, regenerate chunks; refusals change nothing."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr

from shared.errors import InputError, TissueError
from shared.split import canonical_part
from shared.tissue import ScarSpec, TissueSpec
from simgen.meshes import save_mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.solver.simulate import Simulator
from simgen.store.edit import add_subject, added_entries, regenerate
from simgen.store.inspect import store_status
from simgen.store.layout import read_mesh, read_sites, read_tissue
from simgen.store.runner import build
from simgen.store.spec import MeshEntry, spec_hash
from simgen.tissue.defaults import default_settings


@pytest.fixture
def store(reference_store, tmp_path) -> Path:
    """A private copy of the reference build."""
    path = tmp_path / "s.zarr"
    shutil.copytree(reference_store, path)
    return path


@pytest.fixture
def patient(tmp_path) -> MeshEntry:
    """A new geometry from a mesh file."""
    path = save_mesh(lv_ellipsoid(600), tmp_path / "patient.vtu")
    return MeshEntry(id="patient", source=str(path), nodes=600)  # its own size: kept as it is


def snapshot(store: Path) -> dict[str, tuple[bytes, int]]:
    """Relative path -> (bytes, mtime_ns) of every file, the lock excepted."""
    return {
        str(p.relative_to(store)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(store.rglob("*"))
        if p.is_file() and p.name != ".lock"
    }


def bad_tissue() -> TissueSpec:
    """A setting that is valid as data but not on the patient mesh (scar centre node out of range)."""
    return TissueSpec(name="bad", scars=(ScarSpec(region="sphere", node=100000, radius=5.0),))


def test_add_subject_from_mesh_file(store, patient, tiny_spec):
    before = snapshot(store)
    healthy = next(s for s in default_settings() if s.name == "healthy")
    report = add_subject(store, patient, [healthy, "scar-apex"], workers=1)
    assert report.tasks_run == 4 and report.simulations == 12 and not report.failed

    after = snapshot(store)
    changed = {k for k in before if before[k] != after.get(k)}
    assert changed == {"zarr.json"}  # existing groups untouched (bytes and mtimes): only the root metadata
    root = zarr.open_group(str(store), mode="r")
    assert root.attrs["spec_hash"] == spec_hash(tiny_spec()) and root.attrs["complete"] is True
    (entry,) = added_entries(store)
    assert entry["mesh"]["id"] == "patient" and entry["subjects"] == ["patient-healthy", "patient-scar-apex"]
    assert [t["name"] for t in entry["tissue"]] == ["healthy", "scar-apex"]

    # the new subjects are complete and hold what a direct simulation gives
    status = {s.subject_id: (s.chunks_done, s.chunks) for s in store_status(store)}
    assert status == {s: (2, 2) for s in ["lv-healthy", "lv-scar-apex", "patient-healthy", "patient-scar-apex"]}
    mesh = read_mesh(store, "patient")
    assert mesh.n_nodes == lv_ellipsoid(600).n_nodes and root["meshes/patient/electrodes"].shape == (40,)
    g = root["subjects/patient-scar-apex"]
    assert g.attrs["mesh_id"] == "patient" and g["u"].shape == (6, 8, mesh.n_nodes)
    direct = Simulator(mesh, read_tissue(store, "patient-scar-apex"), tiny_spec().solver).run(
        read_sites(store, "patient")
    )
    assert np.array_equal(g["u"][...], direct.u)
    # with consolidated metadata too (plain zarr readers)
    assert "patient-healthy" in dict(zarr.open_consolidated(str(store))["subjects"].groups())

    # the new subjects join the canonical split and the statistics; the others keep theirs (bytes unchanged above)
    subjects = [root[f"subjects/{s}"] for s in status]
    assert [g.attrs["split"] for g in subjects] == [canonical_part(s) for s in status]
    assert root.attrs["statistics"]["u"]["count"] == sum(g.attrs["statistics"]["u"]["count"] for g in subjects)
    assert root.attrs["summary"].startswith("dataset: 4 subjects on 2 mesh(es) of 520-")
    assert entry["provenance"]["created"] == "2024-01-01T00:00:00+00:00"

    # the original spec still recognises the store: nothing to do
    final = build(tiny_spec(), store)
    assert final.tasks_run == 0 and final.tasks_total == 8


def test_add_subject_refusals_write_nothing(store, patient, store_bytes, reference_store):
    with pytest.raises(InputError, match="already has a mesh 'lv'"):
        add_subject(store, MeshEntry(id="lv", source=patient.source), ["healthy"], workers=1)
    with pytest.raises(TissueError, match="subject 'patient-bad'.*100000"):
        add_subject(store, patient, ["healthy", bad_tissue()], workers=1)
    with pytest.raises(InputError, match="unknown tissue setting"):
        add_subject(store, patient, ["healty"], workers=1)
    assert store_bytes(store) == store_bytes(reference_store)
    assert not (store / "meshes/patient").exists()


def test_duplicate_subject_id_is_refused(store, patient, store_bytes, reference_store):
    # mesh "lv-scar" under setting "apex" would be subject "lv-scar-apex", which exists
    twin = MeshEntry(id="lv-scar", source=patient.source)
    apex = TissueSpec(name="apex")
    with pytest.raises(InputError, match=r"already has subject\(s\) \['lv-scar-apex'\]"):
        add_subject(store, twin, [apex], workers=1)
    assert store_bytes(store) == store_bytes(reference_store)


def test_regenerate_corrupted_subject_equals_reference(store, store_bytes, reference_store):
    (store / "subjects/lv-scar-apex/u/c/0/0/0").write_bytes(b"corrupted")
    report = regenerate(store, ["lv-scar-apex"], workers=1)
    assert report.tasks_run == 2 and report.tasks_total == 2
    assert store_bytes(store) == store_bytes(reference_store)


def test_regenerate_site_subset_rewrites_only_that_chunk(store, store_bytes, reference_store):
    before = snapshot(store)
    report = regenerate(store, ["lv-healthy"], sites=[4, 5], workers=1)  # both in chunk 1 (sites 3..5)
    assert report.tasks_run == 1 and report.simulations == 3
    assert store_bytes(store) == store_bytes(reference_store)
    after = snapshot(store)
    rewritten = {k for k in before if before[k][1] != after[k][1]}
    chunk1 = {
        "subjects/lv-healthy/u/c/1/0/0",
        "subjects/lv-healthy/activation/c/1/0",
        "subjects/lv-healthy/moments/c/1/0/0",
        "subjects/lv-healthy/fingerprint/c/1",
        "subjects/lv-healthy/done/c/1",
    }
    assert rewritten - {"zarr.json"} == chunk1  # the subject's statistics are the same: not rewritten


def test_regenerate_refusals_change_nothing(store):
    before = snapshot(store)
    with pytest.raises(InputError, match="unknown subject.*'lv-nope'"):
        regenerate(store, ["lv-healthy", "lv-nope"], workers=1)
    with pytest.raises(InputError, match="site index 6 is out of range for subject 'lv-healthy'"):
        regenerate(store, ["lv-healthy"], sites=[0, 6], workers=1)
    assert snapshot(store) == before


def test_regenerate_keeps_an_unfinished_store_unfinished(store, store_bytes, reference_store, tiny_spec):
    zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")["done"][0] = 0  # an interrupted build
    zarr.open_group(str(store), mode="r+").attrs["complete"] = False
    assert regenerate(store, ["lv-scar-apex"], sites=[0], workers=1).tasks_run == 1
    assert zarr.open_group(str(store), mode="r").attrs["complete"] is False  # lv-healthy/0 is still missing
    assert build(tiny_spec(), store, workers=1).tasks_run == 1  # the build resumes it
    assert store_bytes(store) == store_bytes(reference_store)
