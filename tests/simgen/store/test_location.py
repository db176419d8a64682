"""Store locations (folders and fsspec URLs) and the store lock on URLs, without a cluster.

The lock and the path operations on URLs run here against fsspec's in-memory
filesystem: a non-local backend in one process, enough for everything but
sharing between workers (tests/simgen/store/test_object_store.py does that).
"""

from __future__ import annotations

import json
import os
import socket
import uuid

import fsspec
import pytest

from shared.errors import InputError, SchemaError
from shared.reader import check_store
from simgen.store import location
from simgen.store.location import StoreURLError, store_location
from simgen.store.lock import StoreLock, StoreLocked, unlock
from simgen.store.runner import build


@pytest.fixture
def url():
    """A fresh ``memory://`` store URL, removed afterwards."""
    path = f"/simgen-test-{uuid.uuid4().hex}/s.zarr"
    yield f"memory://{path}"
    fs = fsspec.filesystem("memory")
    if fs.exists(path):
        fs.rm(path, recursive=True)


def test_local_paths_become_absolute_and_file_urls_become_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert store_location("s.zarr") == str(tmp_path / "s.zarr")
    assert store_location(tmp_path / "s.zarr") == str(tmp_path / "s.zarr")
    assert store_location(f"file://{tmp_path}/s.zarr/") == str(tmp_path / "s.zarr")
    assert store_location("s3://bucket/prefix/s.zarr/") == "s3://bucket/prefix/s.zarr"


@pytest.mark.parametrize(
    ("store", "message"),
    [
        ("nosuchproto://bucket/x.zarr", "not a usable fsspec URL: Protocol not known: nosuchproto"),
        ("s3://bucket", "give a prefix inside the bucket"),
        ("s3://", "no path after s3://"),
        ("file://", "no path after file://"),
    ],
)
def test_bad_urls_are_refused_before_anything_is_written(store, message):
    with pytest.raises(StoreURLError, match=message):
        store_location(store)


def test_missing_backend_names_the_package():
    from fsspec.registry import known_implementations as known

    missing = [p for p in ("gs", "az", "hf", "oci") if p in known and _not_importable(known[p]["class"])]
    if not missing:
        pytest.skip("every candidate fsspec backend is installed here")
    with pytest.raises(StoreURLError, match=f"backend of {missing[0]}:// is not installed"):
        store_location(f"{missing[0]}://bucket/x.zarr")


def _not_importable(cls_path: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(cls_path.split(".")[0]) is None


def test_process_local_store_is_refused_for_a_build(url, tiny_spec):
    with pytest.raises(StoreURLError, match="not shared with the Dask workers"):
        build(tiny_spec(), url)
    assert not fsspec.filesystem("memory").exists(url.removeprefix("memory://"))  # nothing written
    assert store_location(url) == url  # reading one in-process is fine


def test_path_operations_on_a_url(url):
    fs, root = location.filesystem(url)
    assert not location.exists(url) and location.entries(url) == []
    fs.pipe({f"{root}/zarr.json": b"{}", f"{root}/.lock": b"{}", f"{root}/subjects/a/zarr.json": b"{}"})
    assert location.exists(url, "zarr.json") and location.exists(url, "subjects/a/zarr.json")
    assert location.entries(url) == [".lock", "subjects", "zarr.json"]
    location.clear(url, keep={".lock"})
    assert location.entries(url) == [".lock"]


def test_check_store_on_a_url_without_a_store(url):
    with pytest.raises(SchemaError, match="not a Zarr store"):
        check_store(url)


def test_url_lock_refuses_a_second_build_and_is_released(url):
    with StoreLock(url) as lock:
        holder = json.loads(fsspec.open(f"{url}/.lock", "rb").open().read())
        assert holder == lock.owner
        with pytest.raises(StoreLocked, match="locked by another build"):
            StoreLock(url).__enter__()
    assert not location.exists(url, ".lock")


def test_url_lock_of_another_host_is_refused_and_named(url):
    fs, root = location.filesystem(url)
    fs.pipe_file(f"{root}/.lock", json.dumps({"host": "node-17", "pid": 4242, "token": "t"}).encode())
    with pytest.raises(StoreLocked, match=r"host node-17, pid 4242.*simgen unlock"):
        StoreLock(url).__enter__()
    with pytest.raises(StoreLocked, match="cannot check.*simgen unlock --force"):
        unlock(url)
    assert unlock(url, force=True) == {"host": "node-17", "pid": 4242, "token": "t"}
    assert unlock(url) is None
    with StoreLock(url):
        pass


@pytest.mark.parametrize("pid", [999_999_999, "own"])
def test_lock_of_a_dead_build_on_this_host_is_taken_over(url, pid):
    """A dead pid, or this process's own pid (a restarted container) while this process holds no lock."""
    fs, root = location.filesystem(url)
    pid = os.getpid() if pid == "own" else pid
    fs.pipe_file(f"{root}/.lock", json.dumps({"host": socket.gethostname(), "pid": pid}).encode())
    with StoreLock(url) as lock:
        assert json.loads(fs.cat_file(f"{root}/.lock"))["token"] == lock.owner["token"]


def test_release_leaves_a_lock_taken_over_by_another_build(url):
    fs, root = location.filesystem(url)
    with StoreLock(url):
        fs.pipe_file(f"{root}/.lock", json.dumps({"host": "other", "pid": 1, "token": "theirs"}).encode())
    assert json.loads(fs.cat_file(f"{root}/.lock"))["token"] == "theirs"


def test_same_process_lock_is_refused_not_taken_over(tmp_path):
    with StoreLock(tmp_path / "s.zarr"):
        with pytest.raises(StoreLocked, match="in this process"):
            StoreLock(str(tmp_path / "s.zarr")).__enter__()


def test_cli_unlock(tmp_path):
    from typer.testing import CliRunner

    from simgen.cli import app

    store = tmp_path / "s.zarr"
    store.mkdir()
    (store / ".lock").write_text(json.dumps({"host": "gone", "pid": 7}))
    refused = CliRunner().invoke(app, ["unlock", str(store)])
    assert refused.exit_code == 2 and "simgen unlock --force" in refused.output  # another host: cannot check
    result = CliRunner().invoke(app, ["unlock", str(store), "--force"])
    assert result.exit_code == 0 and "removed the lock of host gone, pid 7" in " ".join(result.output.split())
    assert "not locked" in CliRunner().invoke(app, ["unlock", str(store)]).output


def test_cli_reports_a_bad_url_as_an_error():
    from typer.testing import CliRunner

    from simgen.cli import app

    result = CliRunner().invoke(app, ["status", "nosuchproto://bucket/x.zarr"])
    assert result.exit_code == 2 and "Protocol not known: nosuchproto" in " ".join(result.output.split())
    assert isinstance(StoreURLError("x"), InputError)
