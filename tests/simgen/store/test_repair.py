"""``simgen repair`` never destroys: every kind of damage is restored to a clean build, or refused with nothing
changed, and no repair computes again a simulation whose data pass every check."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from shared.errors import DamagedData, SchemaError
from shared.reader import read_mesh, read_tissue
from simgen.store.repair import RepairRefused, plan_repair, repair_store
from simgen.store.runner import build
from simgen.store.verify import verify_store


@pytest.fixture
def store(reference_store, tmp_path) -> Path:
    copy = tmp_path / "s.zarr"
    shutil.copytree(reference_store, copy)
    return copy


def _delete(relative: str) -> Callable[[Path], None]:
    return lambda store: (store / relative).unlink()


def _remove_folder(relative: str) -> Callable[[Path], None]:
    return lambda store: shutil.rmtree(store / relative)


def _garble(relative: str) -> Callable[[Path], None]:
    return lambda store: (store / relative).write_text("{not json")


def _flip(relative: str, at: int = 100) -> Callable[[Path], None]:
    def damage(store: Path) -> None:
        data = bytearray((store / relative).read_bytes())
        data[at] ^= 0x10
        (store / relative).write_bytes(bytes(data))

    return damage


def _drop_attribute(relative: str, name: str) -> Callable[[Path], None]:
    def damage(store: Path) -> None:
        meta = json.loads((store / relative).read_text())
        del meta["attributes"][name]
        (store / relative).write_text(json.dumps(meta))

    return damage


H, S = "subjects/lv-healthy", "subjects/lv-scar-apex"
#: Damage kind -> (damage, simulations computed again by the repair: only chunks whose data are damaged). The
#: bad-input suite's damages (a node set, a tissue field, a mesh chunk deleted, shards corrupted, truncated,
#: swapped, deleted, metadata deleted) are repaired by tests/test_bad_input_cli.py.
DAMAGE: dict[str, tuple[Callable[[Path], None], int]] = {
    "mesh points chunk gone": (_delete("meshes/lv/points/c/0/0"), 0),
    "sites chunk gone": (_delete("meshes/lv/stim_nodes/c/0"), 0),
    "mesh group metadata garbled": (_garble("meshes/lv/zarr.json"), 0),
    "mesh digests dropped": (_drop_attribute("meshes/lv/zarr.json", "digests"), 0),
    "mesh group gone": (_remove_folder("meshes/lv"), 0),
    "meshes group metadata gone": (_delete("meshes/zarr.json"), 0),
    "coordinate chunk gone": (_delete(f"{H}/x/c/0"), 0),
    "tissue field metadata gone": (_delete(f"{S}/D/zarr.json"), 0),
    "subject group metadata garbled": (_garble(f"{H}/zarr.json"), 0),
    "subject attribute dropped": (_drop_attribute(f"{H}/zarr.json", "solver"), 0),
    "u metadata garbled": (_garble(f"{S}/u/zarr.json"), 0),
    "done metadata gone": (_delete(f"{H}/done/zarr.json"), 0),
    "done folder gone": (_remove_folder(f"{H}/done"), 0),
    "done flag flipped": (_flip(f"{H}/done/c/1", at=0), 0),
    "subject group gone": (_remove_folder(S), 6),
}


@pytest.mark.usefixtures("reference_commit")
@pytest.mark.parametrize("kind", DAMAGE)
def test_every_damage_is_repaired_to_a_clean_build_computing_only_damaged_chunks(
    kind, store, reference_store, store_bytes
):
    damage, recomputed = DAMAGE[kind]
    damage(store)
    assert not verify_store(store, sample=0).ok, "the damage is found"
    plans = []
    report = repair_store(store, workers=1, on_plan=plans.append)
    assert plans and plans[0] == (plans[0] and report.lines()[: len(plans[0])]), "the plan is printed first"
    assert report.build.simulations == recomputed, report.lines()
    assert store_bytes(store) == store_bytes(reference_store)


def test_a_dry_run_plans_and_writes_nothing(store, store_bytes):
    _delete("meshes/lv/points/c/0/0")(store)
    _flip(f"{H}/u/c/0/0/0")(store)
    damaged = store_bytes(store)
    assert plan_repair(store).lines() == ["arrays written anew from the spec: meshes/lv/points"]
    assert store_bytes(store) == damaged


def test_a_path_that_is_not_a_store_is_refused_and_nothing_written(tmp_path):
    with pytest.raises(SchemaError, match="no store there"):
        repair_store(tmp_path / "mistyped.zarr", workers=1)
    assert not (tmp_path / "mistyped.zarr").exists()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes/todo.txt").write_text("x")
    with pytest.raises(SchemaError, match="is not a simgen store"):
        repair_store(tmp_path / "notes", workers=1)
    assert sorted(p.name for p in (tmp_path / "notes").iterdir()) == ["todo.txt"]


def test_another_spec_is_refused_unless_rescoped(store, store_bytes, tiny_spec_toml, tmp_path):
    other = tmp_path / "other.toml"
    other.write_text(tiny_spec_toml.replace('"scar-apex"', '"scar-apex", "scar-lateral-mid"'))
    before = store_bytes(store)
    with pytest.raises(RepairRefused, match="is not the spec of store .*`--rescope`"):
        repair_store(store, other, workers=1)
    assert store_bytes(store) == before


@pytest.mark.usefixtures("reference_commit")
def test_a_rescope_keeps_the_shared_subjects_and_equals_a_clean_build(store, store_bytes, tiny_spec, tmp_path):
    spec_file = tmp_path / "rescoped.toml"
    spec_file.write_text(
        'tissue = ["healthy", "scar-lateral-mid"]\n[[meshes]]\nid = "lv"\nsource = "lv"\nnodes = 500\n[sites]\n'
        "count = 6\n[solver]\nframes = 8\n[output]\nchunk_sites = 3\nsock_electrodes = 40\n"
    )
    report = repair_store(store, spec_file, workers=1, rescope=True)
    assert report.root == ["spec", "spec_hash"] and report.removed == [S]
    assert report.subjects == ["lv-scar-lateral-mid"] and report.build.simulations == 6  # lv-healthy kept
    clean = tmp_path / "clean.zarr"
    build(tiny_spec(tissue=["healthy", "scar-lateral-mid"]), clean, workers=1)
    assert store_bytes(store) == store_bytes(clean)


def test_a_rescope_that_would_keep_other_results_is_refused(store, store_bytes, tiny_spec_toml, tmp_path):
    other = tmp_path / "frames.toml"
    other.write_text(tiny_spec_toml.replace("frames = 8", "frames = 9"))
    before = store_bytes(store)
    with pytest.raises(RepairRefused, match=r"other \[solver\] settings"):
        repair_store(store, other, workers=1, rescope=True)
    assert store_bytes(store) == before


#: A user's files in a store: a folder of notes, a figure beside the groups, a file in a mesh and a subject group.
USER_FILES = {
    "notes/todo.txt": b"rerun the apex pacing",
    "figure.png": b"\x89PNG\r\n\x1a\n not really",
    "meshes/lv/source.txt": b"from the CT of 2024-03",
    f"{H}/README": b"paced by the lab",
}


def _user_files(store: Path) -> dict[str, bytes]:
    for name, data in USER_FILES.items():
        (store / name).parent.mkdir(parents=True, exist_ok=True)
        (store / name).write_bytes(data)
    return USER_FILES


def _without_user_files(files: dict[str, bytes]) -> dict[str, bytes]:
    return {name: data for name, data in files.items() if name not in USER_FILES}


@pytest.mark.usefixtures("reference_commit")
def test_a_users_files_survive_every_repair_mode_byte_for_byte(
    store, reference_store, store_bytes, tiny_spec, tmp_path
):
    _user_files(store)
    assert verify_store(store, sample=0).ok  # files without Zarr metadata are no damage
    _flip(f"{H}/x/c/0", at=10)(store)
    shutil.copytree(store / f"{H}/x", store / f"{H}/w")  # an extra Zarr array, removed by --remove-extra
    before = store_bytes(store)
    plan_repair(store, remove_extra=True)  # --dry-run
    assert store_bytes(store) == before
    report = repair_store(store, workers=1, remove_extra=True)
    assert report.removed == [f"{H}/w"] and report.arrays == [f"{H}/x"]
    after = store_bytes(store)
    assert {name: after[name] for name in USER_FILES} == USER_FILES
    assert _without_user_files(after) == store_bytes(reference_store)
    spec_file = tmp_path / "rescoped.toml"  # --rescope drops subject lv-scar-apex
    spec_file.write_text(
        'tissue = ["healthy"]\n[[meshes]]\nid = "lv"\nsource = "lv"\nnodes = 500\n[sites]\n'
        "count = 6\n[solver]\nframes = 8\n[output]\nchunk_sites = 3\nsock_electrodes = 40\n"
    )
    assert repair_store(store, spec_file, workers=1, rescope=True).removed == [S]
    clean = tmp_path / "clean.zarr"
    build(tiny_spec(tissue=["healthy"]), clean, workers=1)
    after = store_bytes(store)
    assert {name: after[name] for name in USER_FILES} == USER_FILES
    assert _without_user_files(after) == store_bytes(clean)


def test_a_removal_that_would_touch_a_users_file_is_refused_naming_it(store, store_bytes, tiny_spec_toml, tmp_path):
    shutil.copytree(store / f"{H}/x", store / f"{H}/w")
    (store / f"{H}/w/plot.png").write_bytes(b"a user's figure")
    (store / f"{S}/notes.txt").write_text("scar drawn by hand")
    before = store_bytes(store)
    with pytest.raises(RepairRefused, match=rf"removing {H}/w would delete 1 file\(s\) .*: {H}/w/plot.png"):
        repair_store(store, workers=1, remove_extra=True)
    assert store_bytes(store) == before
    (store / f"{H}/w/plot.png").unlink()
    spec_file = tmp_path / "healthy.toml"
    spec_file.write_text(tiny_spec_toml.replace('"healthy", "scar-apex"', '"healthy"'))
    with pytest.raises(RepairRefused, match=rf"removing {S} would delete 1 file\(s\) .*: {S}/notes.txt"):
        repair_store(store, spec_file, workers=1, rescope=True, remove_extra=True)
    assert store_bytes(store) == {k: v for k, v in before.items() if k != f"{H}/w/plot.png"}


def test_readers_refuse_a_missing_chunk_instead_of_reading_zeros(store):
    _delete("meshes/lv/points/c/0/0")(store)
    _delete(f"{S}/label/c/0")(store)
    with pytest.raises(DamagedData, match=r"mesh lv: points chunk file meshes/lv/points/c/0/0 missing.*simgen repair"):
        read_mesh(store, "lv")
    with pytest.raises(DamagedData, match=r"subject lv-scar-apex: label chunk file .*label/c/0 missing"):
        read_tissue(store, "lv-scar-apex")
