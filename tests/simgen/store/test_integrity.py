"""The store integrity model: damage is named as what it is, builds refuse it, repair restores a clean build."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from zarr.storage import LocalStore

from shared.errors import InputError, SchemaError
from simgen.store.repair import RepairRefused, repair_store
from simgen.store.runner import build
from simgen.store.structure import StoreDamaged
from simgen.store.verify import verify_store


@pytest.fixture
def store(reference_store, tmp_path) -> Path:
    """A private copy of the reference store that a test may damage."""
    copy = tmp_path / "s.zarr"
    shutil.copytree(reference_store, copy)
    return copy


def flip_byte(path: Path, at: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[at] ^= 0x10
    path.write_bytes(bytes(data))


def copy_chunk(store: Path, source: str, target: str, chunk: int) -> None:
    """Copy every file of chunk ``chunk`` of subject ``source`` over subject ``target``'s."""
    for array, key in [("u", f"c/{chunk}/0/0"), ("activation", f"c/{chunk}/0")] + [
        (name, f"c/{chunk}" + "/0/0" * (name == "moments")) for name in ("moments", "fingerprint", "done")
    ]:
        shutil.copyfile(store / "subjects" / source / array / key, store / "subjects" / target / array / key)


@pytest.mark.parametrize(
    "file, expected",
    [
        ("meshes/lv/points/c/0/0", "mesh lv: points checksum mismatch (file meshes/lv/points/c/0/0)"),
        ("meshes/lv/cells/c/0/0", "mesh lv: cells checksum mismatch"),
        ("meshes/lv/electrodes/c/0", "mesh lv: electrodes checksum mismatch"),
        ("subjects/lv-scar-apex/a/c/0", "subject lv-scar-apex: a checksum mismatch (file subjects/lv-scar-apex/a/c/0)"),
        ("subjects/lv-scar-apex/label/c/0", "subject lv-scar-apex: label checksum mismatch"),
        ("subjects/lv-healthy/x/c/0", "subject lv-healthy: x checksum mismatch"),
        (
            "subjects/lv-healthy/done/c/1",
            "subject lv-healthy: done flag of chunk 1 checksum mismatch (file subjects/lv-healthy/done/c/1)",
        ),
    ],
)
def test_corrupted_small_array_is_named_as_what_it_is(store, file, expected):
    flip_byte(store / file)
    problems = verify_store(store, sample=0).problems
    assert problems and problems[0].startswith(expected), problems
    assert not any("differs from recomputation" in p for p in verify_store(store).problems)


def test_missing_subject_group_is_named(store):
    shutil.rmtree(store / "subjects/lv-scar-apex")
    assert verify_store(store, sample=0).problems == ["subject lv-scar-apex: group missing (subjects/lv-scar-apex)"]


def test_missing_and_extra_arrays_are_named(store):
    shutil.rmtree(store / "subjects/lv-healthy/fingerprint")
    shutil.copytree(store / "subjects/lv-healthy/x", store / "subjects/lv-healthy/w")
    shutil.copytree(store / "meshes/lv", store / "meshes/rv")
    problems = verify_store(store, sample=0).problems
    assert "store: extra group meshes/rv (not implied by the recorded spec)" in problems
    assert "subject lv-healthy: array fingerprint missing" in problems
    assert "subject lv-healthy: extra array subjects/lv-healthy/w (not implied by the recorded spec)" in problems


def test_wrong_codec_is_named(store):
    meta = store / "subjects/lv-healthy/a/zarr.json"
    data = json.loads(meta.read_text())
    data["codecs"] = [c for c in data["codecs"] if c["name"] != "crc32c"]  # no checksum: still decodes
    meta.write_text(json.dumps(data))
    problems = verify_store(store, sample=0).problems
    assert len(problems) == 1 and problems[0].startswith("subject lv-healthy: a has codecs"), problems


@pytest.mark.parametrize("whole", [False, True], ids=["u-file", "all-chunk-files"])
def test_chunk_copied_over_another_subjects_is_caught_by_the_default_verify(store, whole):
    if whole:  # data, moments, fingerprint and flag: each file intact, the moments agree with the data
        copy_chunk(store, "lv-healthy", "lv-scar-apex", 0)
    else:
        shutil.copyfile(store / "subjects/lv-healthy/u/c/0/0/0", store / "subjects/lv-scar-apex/u/c/0/0/0")
    report = verify_store(store)
    assert report.problems and report.problems[0].startswith("subject lv-scar-apex chunk 0 (sites 0..2)")
    if whole:
        assert "content fingerprint differs" in report.problems[0]


def test_chunk_moved_between_sites_is_caught(store):
    for array, key in [("u", "c/{}/0/0"), ("activation", "c/{}/0"), ("moments", "c/{}/0/0"), ("fingerprint", "c/{}")]:
        folder = store / "subjects/lv-healthy" / array
        shutil.copyfile(folder / key.format(0), folder / key.format(1))
    problems = verify_store(store, sample=0).problems
    assert len(problems) == 1 and "chunk 1 (sites 3..5): content fingerprint differs" in problems[0], problems


def test_every_subject_is_recomputed_by_default(reference_store):
    report = verify_store(reference_store)
    assert report.ok and report.chunks_recomputed == 2  # one chunk of each of the two subjects


def test_build_refuses_a_damaged_store_with_the_repair_command(store, tiny_spec):
    shutil.rmtree(store / "subjects/lv-healthy")
    with pytest.raises(StoreDamaged, match=r"subject lv-healthy: group missing.*`simgen repair .*s\.zarr`"):
        build(tiny_spec(), store, workers=1)
    assert not (store / "subjects/lv-healthy").exists()


def test_cli_build_on_a_damaged_store_exits_2_without_traceback(store, tiny_spec_toml, tmp_path):
    flip_byte(store / "meshes/lv/points/c/0/0")
    spec = tmp_path / "tiny.toml"
    spec.write_text(tiny_spec_toml)
    proc = subprocess.run(
        [sys.executable, "-P", "-m", "simgen.cli", "build", str(spec), "--store", str(store), "--workers", "1"],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "400"},
        timeout=300,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert "Traceback" not in out and "mesh lv: points checksum mismatch" in out and "simgen repair" in out


def test_repair_restores_a_byte_identical_store(store, reference_store, store_bytes):
    flip_byte(store / "meshes/lv/points/c/0/0")
    flip_byte(store / "subjects/lv-scar-apex/a/c/0")
    flip_byte(store / "subjects/lv-healthy/done/c/1")
    flip_byte(store / "subjects/lv-healthy/u/c/0/0/0", at=100)
    copy_chunk(store, "lv-healthy", "lv-scar-apex", 1)
    shutil.copytree(store / "subjects/lv-healthy/x", store / "subjects/lv-healthy/w")
    assert not verify_store(store, sample=0).ok
    damaged = store_bytes(store)
    with pytest.raises(RepairRefused, match=r"1 member\(s\) its recorded spec does not imply: subjects/lv-healthy/w"):
        repair_store(store, workers=1)
    assert store_bytes(store) == damaged
    report = repair_store(store, workers=1, remove_extra=True)
    assert report.arrays == ["meshes/lv/points", "subjects/lv-scar-apex/a"] and not report.subjects
    assert report.removed == ["subjects/lv-healthy/w"]
    assert report.chunks == ["lv-healthy/0", "lv-scar-apex/1"] and report.flags == ["lv-healthy/1"]
    assert report.build.tasks_run == 2  # the sound chunks are kept
    assert store_bytes(store) == store_bytes(reference_store)
    assert verify_store(store).ok


def test_repair_of_a_sound_store_changes_nothing(store, reference_store, store_bytes):
    report = repair_store(store, workers=1)
    assert not report.lines() and report.build.tasks_run == 0
    assert store_bytes(store) == store_bytes(reference_store)


def drop_root_attributes(store: Path, *names: str) -> None:
    path = store / "zarr.json"
    meta = json.loads(path.read_text())
    for name in names:
        del meta["attributes"][name]
    path.write_text(json.dumps(meta))


@pytest.mark.usefixtures("reference_commit")
def test_repair_restores_a_missing_provenance_from_the_recorded_spec(store, reference_store, store_bytes):
    drop_root_attributes(store, "provenance", "simulation")
    report = repair_store(store, workers=1)
    assert report.lines() == ["root attributes restored: provenance, simulation"]
    assert store_bytes(store) == store_bytes(reference_store)  # SOURCE_DATE_EPOCH: the same creation date


@pytest.mark.usefixtures("reference_commit")
@pytest.mark.parametrize("garbage", [False, True], ids=["deleted", "not-json"])
def test_repair_without_root_metadata_needs_the_spec_file(
    store, reference_store, store_bytes, tiny_spec_toml, tmp_path, garbage
):
    if garbage:
        (store / "zarr.json").write_text("{not json")
    else:
        (store / "zarr.json").unlink()
    damaged = store_bytes(store)
    with pytest.raises(SchemaError, match=r"root metadata \(zarr\.json\) is missing or unreadable.*--spec SPEC"):
        repair_store(store, workers=1)
    other = tmp_path / "other.toml"
    other.write_text(tiny_spec_toml.replace("count = 6", "count = 5"))
    with pytest.raises(SchemaError, match=r"other\.toml is not the spec of store .*stim_nodes has shape \(6,\)"):
        repair_store(store, other, workers=1)
    assert store_bytes(store) == damaged  # nothing written by a repair that cannot finish
    spec = tmp_path / "tiny.toml"
    spec.write_text(tiny_spec_toml)
    report = repair_store(store, spec, workers=1)
    assert report.root == ["complete", "provenance", "schema_version", "simulation", "spec", "spec_hash", "split"]
    assert store_bytes(store) == store_bytes(reference_store)


@pytest.mark.usefixtures("reference_commit")
def test_repair_finishes_a_layout_cut_short_by_a_full_disk(
    tmp_path, reference_store, store_bytes, tiny_spec, monkeypatch
):
    spec, store = tiny_spec(), tmp_path / "full.zarr"
    real = LocalStore.set

    async def full(self, key, value, *args, **kw):
        if key.startswith("subjects/lv-scar-apex") or key == "subjects/zarr.json":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), key)
        return await real(self, key, value, *args, **kw)

    with monkeypatch.context() as patch:
        patch.setattr(LocalStore, "set", full)
        with pytest.raises(OSError, match="No space left on device"):
            build(spec, store, workers=1)
    report = repair_store(store, workers=1)
    assert report.groups == ["subjects"] and report.subjects == ["lv-scar-apex"], report.lines()
    assert store_bytes(store) == store_bytes(reference_store)


def test_a_repair_that_cannot_finish_writes_nothing(store, store_bytes, tmp_path):
    from simgen.meshes import save_mesh
    from simgen.meshes.ellipsoid import lv_ellipsoid
    from simgen.store.edit import add_subject
    from simgen.store.spec import MeshEntry

    path = save_mesh(lv_ellipsoid(400), tmp_path / "patient.vtu")
    add_subject(store, MeshEntry(id="patient", source=str(path), nodes=400), ["healthy"], workers=1)
    path.unlink()  # the added mesh cannot be made again
    shutil.copytree(store / "subjects/lv-healthy/x", store / "subjects/lv-healthy/w")  # an extra array to remove
    (store / "meshes/patient/zarr.json").unlink()
    damaged = store_bytes(store)
    with pytest.raises(InputError, match="patient.vtu"):
        repair_store(store, workers=1, remove_extra=True)
    assert store_bytes(store) == damaged
