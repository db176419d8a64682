"""Builds into an object store: s3:// on a local S3 emulator (moto server) with real worker processes.

The emulator listens on 127.0.0.1 only. Driver and workers find it as a real
deployment would: through ``AWS_ENDPOINT_URL`` and the ``AWS_*`` credentials
in their environment (the workers inherit them when they start).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("s3fs", reason="s3fs is not installed (pip install -e '.[dev]')")
if shutil.which("moto_server", path=str(Path(sys.executable).parent)) is None:
    pytest.skip("moto_server is not installed (pip install 'moto[server]')", allow_module_level=True)

from simgen.store.inspect import store_status  # noqa: E402
from simgen.store.layout import StoreMismatch  # noqa: E402
from simgen.store.location import filesystem  # noqa: E402
from simgen.store.lock import StoreLock, StoreLocked  # noqa: E402
from simgen.store.runner import build  # noqa: E402
from simgen.store.verify import verify_store  # noqa: E402

BUCKET = "simgen-test"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def s3_endpoint():
    """A moto S3 server on 127.0.0.1 with one bucket; the AWS_* variables point at it."""
    port = _free_port()
    endpoint = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    env = {
        "AWS_ENDPOINT_URL": endpoint,
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(endpoint, timeout=2)
                break
            except OSError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the moto S3 server did not start") from None
                time.sleep(0.2)
        fs, _ = filesystem(f"s3://{BUCKET}/x")
        fs.mkdir(BUCKET)
        yield endpoint
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def object_bytes(url: str) -> dict[str, bytes]:
    """Every object under ``url`` (relative key -> bytes), the lock excepted."""
    fs, root = filesystem(url)
    fs.invalidate_cache()
    keys = [k for k in fs.find(root) if not k.endswith("/.lock")]
    return {k[len(root) + 1 :]: v for k, v in fs.cat(keys).items()}


@pytest.fixture(scope="module")
def cluster(s3_endpoint):
    """Two single-threaded worker processes, shared by the s3:// and the local build (one start-up).

    Started after the ``AWS_*`` variables are set: the workers inherit them.
    """
    from distributed import LocalCluster

    from simgen.store.runner import single_thread_env

    with (
        single_thread_env(),
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c,
    ):
        yield c.scheduler_address


@pytest.fixture(scope="module")
def s3_store(s3_endpoint, cluster, tiny_spec):
    """The tiny spec built into s3:// by the two worker processes."""
    url = f"s3://{BUCKET}/builds/tiny.zarr"
    report = build(tiny_spec(), url, scheduler=cluster)
    assert report.tasks_run == report.tasks_total == 4
    return url


@pytest.fixture(scope="module")
def local_store(cluster, tiny_spec, tmp_path_factory):
    """The same build into a local folder."""
    store = tmp_path_factory.mktemp("local") / "tiny.zarr"
    build(tiny_spec(), store, scheduler=cluster)
    return store


def test_s3_build_is_byte_identical_to_a_local_build(s3_store, local_store, store_bytes):
    remote, local = object_bytes(s3_store), store_bytes(local_store)
    assert sorted(remote) == sorted(local)
    chunks = [k for k in local if "/c/" in k]
    assert any(k.startswith("subjects/lv-healthy/u/c/") for k in chunks)
    assert all(remote[k] == local[k] for k in chunks), "chunk data differ"
    assert remote == local  # metadata too


def test_s3_store_reads_back_verifies_and_resumes(s3_store, tiny_spec):
    assert [(r.subject_id, r.chunks_done, r.chunks) for r in store_status(s3_store)] == [
        ("lv-healthy", 2, 2),
        ("lv-scar-apex", 2, 2),
    ]
    report = verify_store(s3_store, sample=1)
    assert report.ok and report.chunks_checked == 4 and report.chunks_recomputed == 2  # one per subject
    assert build(tiny_spec(), s3_store).tasks_run == 0  # resume: nothing left, no cluster started


def test_s3_lock_and_refusals(s3_store, tiny_spec):
    with StoreLock(s3_store):
        with pytest.raises(StoreLocked, match="locked by another build"):
            build(tiny_spec(), s3_store)
    with pytest.raises(StoreMismatch, match="different spec"):
        build(tiny_spec(solver={"frames": 9}), s3_store)
    fs, root = filesystem(s3_store)
    assert not fs.exists(f"{root}/.lock")


def test_missing_bucket_is_a_clear_error(s3_endpoint, tiny_spec):
    from simgen.store.location import StoreURLError

    with pytest.raises(StoreURLError, match=r"cannot write the lock s3://no-such-bucket/x.zarr/.lock.*must exist"):
        build(tiny_spec(), "s3://no-such-bucket/x.zarr")


def test_s3_repair_restores_what_was_deleted_and_keeps_every_simulation(s3_store, local_store, store_bytes, cluster):
    from simgen.store.repair import repair_store

    fs, root = filesystem(s3_store)
    fs.rm_file(f"{root}/meshes/lv/points/c/0/0")
    fs.rm_file(f"{root}/subjects/lv-healthy/zarr.json")
    report = repair_store(s3_store, scheduler=cluster)
    assert report.arrays == ["meshes/lv/points"] and report.groups == ["subjects/lv-healthy"]
    assert report.build.simulations == 0
    assert object_bytes(s3_store) == store_bytes(local_store)
