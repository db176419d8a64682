"""Builds with the torch backend and on GPU workers: spec setting, hash, GPU cluster, verify, refusals.

Without a GPU the GPU-worker path runs with the device list faked
(:func:`simgen.store.runner.cuda_devices`): the workers then see
``CUDA_VISIBLE_DEVICES`` and the resource ``GPU``, and torch runs on their CPU.
"""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
import torch
import zarr
from typer.testing import CliRunner

from shared.errors import ConfigError, InputError
from simgen.cli import app
from simgen.solver.backends import BACKEND_TOLERANCE
from simgen.solver.simulate import SimulationResult
from simgen.store import runner
from simgen.store.layout import StoreMismatch
from simgen.store.runner import GPUCluster, build
from simgen.store.spec import spec_hash, spec_to_dict
from simgen.store.verify import verify_store

NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal where no GPU is present")
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")

#: spec_hash(tiny_spec()) as written before [solver] backend existed: stores of such specs still resume.
HASH_BEFORE_BACKEND = "7d55045e476bf96c9ded876072caadcd10f31090368bc96aeade3e16f1d4c252"


def torch_spec(tiny_spec, backend: str = "torch"):
    return tiny_spec(solver={"frames": 8, "backend": backend})


def test_unset_backend_keeps_the_hash_of_older_stores(reference_store, tiny_spec):
    spec = tiny_spec()
    assert spec.solver.backend is None and "backend" not in spec_to_dict(spec)["solver"]
    assert spec_hash(spec) == HASH_BEFORE_BACKEND
    assert zarr.open_group(str(reference_store), mode="r").attrs["spec_hash"] == HASH_BEFORE_BACKEND
    assert spec_to_dict(torch_spec(tiny_spec))["solver"]["backend"] == "torch"
    assert spec_hash(torch_spec(tiny_spec)) != HASH_BEFORE_BACKEND


def test_store_without_backend_resumes_and_refuses_a_backend_change(reference_store, tmp_path, tiny_spec):
    store = tmp_path / "s.zarr"
    shutil.copytree(reference_store, store)
    zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")["done"][1] = 0
    zarr.open_group(str(store), mode="r+").attrs["complete"] = False
    with pytest.raises(StoreMismatch, match="different spec"):
        build(torch_spec(tiny_spec), store, workers=1)
    assert build(tiny_spec(), store, workers=1).tasks_run == 1


def test_unknown_backend_in_a_spec_names_the_allowed_ones(tiny_spec):
    with pytest.raises(ConfigError, match=r"solver.backend: 'cuda' is not one of \['numba', 'torch', 'auto'\]"):
        tiny_spec(solver={"backend": "cuda"})


def test_gpu_build_through_gpu_workers_passes_verify(reference_store, tmp_path, tiny_spec, monkeypatch):
    """--gpus 1 with the device list faked: one GPU worker, tasks with resource GPU=1, torch (on its CPU);
    the store passes `simgen verify`, which recomputes chunks with numba within the backend tolerance."""
    monkeypatch.setattr(runner, "cuda_devices", lambda gpus: ["0"])
    store = tmp_path / "gpu.zarr"
    report = build(torch_spec(tiny_spec), store, gpus=1)
    assert report.tasks_run == 4
    verified = verify_store(store, sample=2)
    assert verified.ok, verified.problems
    assert verified.chunks_recomputed == 4
    u_tol, _ = BACKEND_TOLERANCE
    stored, reference = zarr.open_group(str(store), mode="r"), zarr.open_group(str(reference_store), mode="r")
    for subject in ("lv-healthy", "lv-scar-apex"):
        u, u_ref = stored[f"subjects/{subject}/u"][...], reference[f"subjects/{subject}/u"][...]
        assert 0 < np.abs(u - u_ref).max() <= u_tol  # torch: close to numba, not bitwise


def test_verify_admits_the_backend_tolerance_only_for_torch_stores():
    from simgen.store.verify import ChunkRef, _recomputed_differences

    u_tol, steps = BACKEND_TOLERANCE
    dt = 0.05
    ref = ChunkRef("lv-healthy", 0, 0, 1)
    result = SimulationResult(
        np.zeros(1, np.int64),
        np.ones(2),
        np.zeros((1, 2, 3), np.float32),
        np.array([[0.0, 1.0, np.nan]], np.float32),
        dt,
    )
    close = (result.u + 0.5 * u_tol, result.activation + np.float32(0.5 * steps * dt))
    assert _recomputed_differences(ref, *close, result, exact=False) == []
    assert len(_recomputed_differences(ref, *close, result, exact=True)) == 2  # numba stores: bit for bit
    far = (result.u + 2 * u_tol, result.activation + np.float32(2 * steps * dt))
    problems = _recomputed_differences(ref, *far, result, exact=False)
    assert len(problems) == 2 and all("admitted between solver backends" in p for p in problems)
    moved_nan = np.array([[0.0, np.nan, 1.0]], np.float32)
    assert _recomputed_differences(ref, result.u, moved_nan, result, exact=False)


def test_gpu_cluster_gives_each_worker_one_gpu_and_the_resource():
    with GPUCluster(["0", "3"], dashboard_address=":0") as cluster, runner.Client(cluster) as client:
        client.wait_for_workers(2)
        seen = client.run(lambda: os.environ["CUDA_VISIBLE_DEVICES"])
        assert sorted(seen.values()) == ["0", "3"]
        assert len(runner.gpu_workers(client)) == 2


@NO_CUDA
def test_gpus_without_a_gpu_is_refused_by_the_cli(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[[meshes]]\nid = "lv"\nnodes = 300\n[solver]\nbackend = "torch"\n')
    result = CliRunner().invoke(app, ["build", str(spec), "--store", str(tmp_path / "x.zarr"), "--gpus", "1"])
    assert result.exit_code == 2
    assert "no CUDA device for --gpus 1" in " ".join(result.output.split())
    assert not (tmp_path / "x.zarr").exists()


def test_gpus_need_a_torch_backend_in_the_spec(tmp_path, tiny_spec, monkeypatch):
    monkeypatch.setattr(runner, "cuda_devices", lambda gpus: ["0"] * gpus)
    with pytest.raises(ConfigError, match=r"--gpus runs the torch solver backend, but the spec's is 'numba'"):
        build(tiny_spec(), tmp_path / "x.zarr", gpus=1)
    assert not (tmp_path / "x.zarr").exists()


def test_gpus_on_a_cluster_without_gpu_workers_is_refused(tmp_path, tiny_spec):
    with runner.LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=":0") as cluster:
        with pytest.raises(InputError, match="no worker of the cluster at .* offers a GPU.*--resources GPU=1"):
            with runner.dask_client(cluster.scheduler_address, 1, gpus=1):
                pass


@CUDA
def test_gpu_build_on_a_real_gpu_passes_verify(tmp_path, tiny_spec):
    store = tmp_path / "gpu.zarr"
    build(torch_spec(tiny_spec, "auto"), store, gpus=1)
    verified = verify_store(store, sample=2)
    assert verified.ok, verified.problems
