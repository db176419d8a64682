"""Builds on real processes: `dask scheduler` + `dask worker` on 127.0.0.1, killed workers and clients.

Each test compares the resulting store byte for byte with an uninterrupted
build of the same spec.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import zarr

from simgen.store import load_spec
from simgen.store.runner import SINGLE_THREAD_ENV, build

BIN = Path(sys.executable).parent

# 2 subjects x 6 chunks of 3 sites on a 3,000-node LV: long enough to kill something mid-build.
SPEC = """
name = "kill-test"
tissue = ["healthy", "scar-septal-mid"]
[[meshes]]
id = "lv"
nodes = 3000
[sites]
count = 18
[solver]
frames = 40
[output]
chunk_sites = 3
sock_electrodes = 60
"""


def chunks_done(store: Path) -> int:
    try:
        with warnings.catch_warnings():  # a poll may see a writer's temporary *.partial file
            warnings.simplefilter("ignore")
            root = zarr.open_group(str(store), mode="r")
            return int(sum(g["done"][...].sum() for _, g in root["subjects"].groups()))
    except Exception:  # layout not written yet
        return 0


def wait_for(predicate, timeout: float = 120.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.02)


def store_bytes(store: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(store)): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file() and p.name != ".lock"
    }


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "kill.toml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def reference(spec_file, tmp_path_factory) -> Path:
    store = tmp_path_factory.mktemp("ref") / "ref.zarr"
    build(load_spec(spec_file), store, workers=2)
    return store


def _spawn(*args: str) -> subprocess.Popen:
    env = {**os.environ, **SINGLE_THREAD_ENV}
    return subprocess.Popen(args, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


@pytest.fixture
def cluster(tmp_path):
    """A scheduler and two single-threaded workers, started as the deploy files do."""
    sched_file = tmp_path / "scheduler.json"
    procs = [
        _spawn(
            str(BIN / "dask"),
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            str(sched_file),
        )
    ]
    try:
        wait_for(sched_file.exists, 60, "the scheduler file")
        time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        workers = [
            _spawn(
                str(BIN / "dask"),
                "worker",
                address,
                "--nthreads",
                "1",
                "--nworkers",
                "1",
                "--name",
                f"w{i}",
                "--no-dashboard",
            )
            for i in range(2)
        ]
        procs += workers
        from distributed import Client

        with Client(address) as client:
            client.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for proc in reversed(procs):
            _kill(proc)


def test_build_on_external_cluster_survives_a_killed_worker(cluster, spec_file, reference, tmp_path):
    address, workers = cluster
    store = tmp_path / "s.zarr"
    result: dict = {}
    thread = threading.Thread(target=lambda: result.update(report=build(load_spec(spec_file), store, address)))
    thread.start()
    wait_for(lambda: chunks_done(store) >= 1, what="the first chunk")
    _kill(workers[0])  # the nanny and its worker, for good
    done_at_kill = chunks_done(store)
    thread.join(timeout=300)
    assert result["report"].tasks_run == 12
    assert done_at_kill < 12, "the build finished before the worker was killed; the test proves nothing"
    assert store_bytes(store) == store_bytes(reference)


def test_killed_client_resumes_to_an_identical_store(spec_file, reference, tmp_path):
    store = tmp_path / "s.zarr"
    proc = _spawn(str(BIN / "simgen"), "build", str(spec_file), "--store", str(store), "--workers", "2")
    try:
        wait_for(lambda: chunks_done(store) >= 2, what="two chunks")
    finally:
        _kill(proc)  # SIGKILL the client, its scheduler and its workers
    assert not zarr.open_group(str(store), mode="r").attrs["complete"]
    partial = chunks_done(store)
    report = build(load_spec(spec_file), store, workers=2)  # takes over the dead build's lock
    assert report.tasks_run == 12 - partial
    assert store_bytes(store) == store_bytes(reference)
    data = zarr.open_group(str(store), mode="r")["subjects/lv-healthy/u"][...]
    assert np.isfinite(data).all()
