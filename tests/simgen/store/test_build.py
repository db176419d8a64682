"""Dataset builds on a local Dask cluster: contents, resume, refusals, failures."""

from __future__ import annotations

import json
import os
import shutil
import warnings

import numpy as np
import pytest
import xarray as xr
import zarr

from shared.errors import ConfigError, InputError, MeshError, SchemaError, StimulusError, TimeStepError, TissueError
from shared.schema import SCHEMA_VERSION
from simgen.solver.simulate import Simulator
from simgen.store import make_plan, spec_hash
from simgen.store.inspect import store_status
from simgen.store.layout import StoreMismatch, check_store, create_layout, read_mesh, read_tissue
from simgen.store.lock import StoreLock, StoreLocked
from simgen.store.runner import BuildFailed, build, dry_run
from simgen.store.spec import spec_from_mapping, spec_to_dict
from simgen.store.structure import StoreDamaged


def test_store_contents_match_direct_simulation(reference_store, tiny_spec):
    root = zarr.open_group(str(reference_store), mode="r")
    assert root.attrs["schema_version"] == SCHEMA_VERSION and root.attrs["complete"] is True
    assert root.attrs["spec_hash"] == spec_hash(tiny_spec())
    plan = make_plan(tiny_spec())
    for subject in plan.subjects:
        g = root[f"subjects/{subject.id}"]
        assert g["done"][...].all()
        assert g["u"].metadata.dimension_names == ("site", "time", "node")
        sites = root["meshes/lv/stim_nodes"][...]
        direct = Simulator(
            read_mesh(reference_store, "lv"), read_tissue(reference_store, subject.id), plan.spec.solver
        ).run(sites)
        assert np.array_equal(g["u"][...], direct.u)  # bitwise: chunking and workers do not matter
        assert np.array_equal(g["activation"][...], direct.activation, equal_nan=True)


def test_store_opens_with_xarray(reference_store):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = xr.open_zarr(reference_store, group="subjects/lv-healthy")
    assert ds["u"].dims == ("site", "time", "node") and ds["u"].shape[:2] == (6, 8)
    assert ds["activation"].dims == ("site", "node")


def test_resume_after_lost_chunks_is_bitwise_identical(reference_store, tmp_path, tiny_spec, store_bytes):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    # a crash after some chunks: flags cleared, data of those chunks missing or half-written
    g = zarr.open_group(str(store), path="subjects/lv-scar-apex", mode="r+")
    g["done"][1] = 0
    shutil.rmtree(store / "subjects/lv-scar-apex/u/c/1")
    zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")["done"][0] = 0
    (store / "subjects/lv-healthy/u/c/0/0/0").write_bytes(b"truncated")
    zarr.open_group(str(store), mode="r+").attrs["complete"] = False
    report = build(tiny_spec(), store, workers=1)
    assert report.tasks_run == 2
    assert store_bytes(store) == store_bytes(reference_store)


def test_complete_store_is_not_rebuilt(reference_store, tmp_path, tiny_spec, store_bytes):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    assert build(tiny_spec(), store).tasks_run == 0
    assert store_bytes(store) == store_bytes(reference_store)


def test_different_spec_is_refused_unless_forced(reference_store, tmp_path, tiny_spec, store_bytes):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    other = tiny_spec(solver={"frames": 9})
    with pytest.raises(StoreMismatch, match="different spec"):
        build(other, store)
    assert store_bytes(store) == store_bytes(reference_store)  # untouched
    build(other, store, force=True, workers=1)
    assert zarr.open_group(str(store), mode="r")["subjects/lv-healthy/u"].shape[1] == 9


def test_dry_run_refuses_what_the_build_refuses_and_writes_nothing(reference_store, tmp_path, tiny_spec, store_bytes):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    assert dry_run(tiny_spec(), tmp_path / "new.zarr") == "new" and not (tmp_path / "new.zarr").exists()
    assert dry_run(tiny_spec(), store) == "resume"
    with pytest.raises(StoreMismatch, match="different spec"):
        dry_run(tiny_spec(solver={"frames": 9}), store)
    assert dry_run(tiny_spec(solver={"frames": 9}), store, force=True) == "replace"
    with StoreLock(store):
        with pytest.raises(StoreLocked, match="locked by another build"):
            dry_run(tiny_spec(), store)
    assert store_bytes(store) == store_bytes(reference_store)
    (store / "subjects/lv-healthy/zarr.json").unlink()
    damaged = store_bytes(store)
    with pytest.raises(StoreDamaged, match=r"group metadata \(subjects/lv-healthy/zarr\.json\) missing"):
        dry_run(tiny_spec(), store)
    assert dry_run(tiny_spec(), store, force=True) == "replace"
    assert store_bytes(store) == damaged


@pytest.mark.usefixtures("reference_commit")
def test_force_rebuilds_a_damaged_store_of_the_same_spec(reference_store, tmp_path, tiny_spec, store_bytes):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    (store / "subjects/lv-healthy/zarr.json").unlink()
    with pytest.raises(StoreDamaged, match="simgen repair"):
        build(tiny_spec(), store, workers=1)
    build(tiny_spec(), store, force=True, workers=1)
    assert store_bytes(store) == store_bytes(reference_store)


def test_second_writer_is_refused(tmp_path, tiny_spec):
    store = tmp_path / "s.zarr"
    with StoreLock(store):
        with pytest.raises(StoreLocked, match="locked by another build"):
            build(tiny_spec(), store)
    assert not (store / ".lock").exists()


def test_lock_of_a_killed_build_is_taken_over(tmp_path):
    store = tmp_path / "s.zarr"
    store.mkdir()
    import socket

    (store / ".lock").write_text(f'{{"host": "{socket.gethostname()}", "pid": 999999999}}')
    with StoreLock(store):
        owner = json.loads((store / ".lock").read_text())
        assert (owner["host"], owner["pid"]) == (socket.gethostname(), os.getpid())
    assert not (store / ".lock").exists()


def test_failing_task_is_named_and_finished_chunks_kept(tmp_path, tiny_spec):
    spec = tiny_spec()
    store = tmp_path / "s.zarr"
    create_layout(store, make_plan(spec), spec_to_dict(spec), spec_hash(spec))
    (store / "subjects/lv-scar-apex/u/c/0/0/0").mkdir(parents=True)  # a folder where its first shard goes
    with pytest.raises(BuildFailed, match="lv-scar-apex/0") as info:
        build(spec, store, workers=2, retries=1)
    assert "lv-healthy" not in str(info.value)
    status = {s.subject_id: s.chunks_done for s in store_status(store)}
    assert status == {"lv-healthy": 2, "lv-scar-apex": 1}  # only the task that could not write failed
    assert zarr.open_group(str(store), mode="r").attrs["complete"] is False


@pytest.mark.parametrize(
    "patch, error, match",
    [
        ({"meshes": [{"id": "lv", "source": "heart.xyz"}]}, MeshError, "unknown mesh"),
        (
            {
                "custom_tissue": [
                    {"name": "bad", "scars": [{"region": "sphere", "node": 3, "radius": 5.0, "core": {"a": 0.9}}]}
                ]
            },
            TissueError,
            "excitability",
        ),
        ({"sites": {"nodes": [3, 100000]}}, StimulusError, "100000"),
        ({"solver": {"frames": 8, "dt": 10.0}}, TimeStepError, "unstable"),
        ({"solver": {"frames": 8, "dtt": 0.1}}, ConfigError, "dtt"),
    ],
)
def test_bad_specs_write_nothing(tmp_path, patch, error, match, tiny_spec):
    store = tmp_path / "s.zarr"
    with pytest.raises(error, match=match):
        build(tiny_spec(**patch) if error is not ConfigError else spec_from_mapping(patch), store)
    assert not store.exists()


def test_schema_version_mismatch_is_refused(reference_store, tmp_path, tiny_spec):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    zarr.open_group(str(store), mode="r+").attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(SchemaError, match="schema_version"):
        check_store(store)
    with pytest.raises(SchemaError):
        build(tiny_spec(), store)
    with pytest.raises(InputError, match="not a Zarr store"):
        check_store(tmp_path)


def test_subject_workers_balance_pending_chunks_and_keep_each_subject_on_one_worker():
    from simgen.store.manifest import Task
    from simgen.store.runner import subject_workers

    tasks = [Task(s, c, 10 * c, 10 * c + 10) for s, n in (("a", 4), ("b", 3), ("c", 2), ("d", 1)) for c in range(n)]
    home = subject_workers(tasks, ["w1", "w2"])
    assert set(home) == {"a", "b", "c", "d"} and all(len(w) == 1 for w in home.values())
    load = {w: sum(1 for t in tasks if home[t.subject_id] == [w]) for w in ("w1", "w2")}
    assert load == {"w1": 5, "w2": 5}  # a + d on one worker, b + c on the other
    assert subject_workers(tasks, ["w1"]) == {}
