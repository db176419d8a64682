"""The store lock tells a running owner from a gone one by pid and start time; `unlock` refuses a running one."""

from __future__ import annotations

import json
import os
import socket
import subprocess
from pathlib import Path

import pytest

from simgen.store.lock import StoreLock, StoreLocked, _start_time, unlock

needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="start times come from /proc")


@pytest.fixture
def other_process():
    """A live process of this host that is no build: its pid and start time."""
    proc = subprocess.Popen(["sleep", "60"])
    yield proc.pid, _start_time(proc.pid)
    proc.kill()
    proc.wait()


def write_lock(store: Path, **owner) -> None:
    store.mkdir(exist_ok=True)
    (store / ".lock").write_text(json.dumps({"host": socket.gethostname(), "token": "t", **owner}))


@needs_proc
def test_start_time_is_read_from_proc(other_process):
    pid, start = other_process
    assert isinstance(start, int) and start == _start_time(pid)
    assert _start_time(os.getpid()) <= start  # the child started after this process
    assert _start_time(999_999_999) is None


@needs_proc
def test_lock_records_host_pid_and_start_time(tmp_path):
    with StoreLock(tmp_path / "s.zarr"):
        owner = json.loads((tmp_path / "s.zarr/.lock").read_text())
    assert owner["host"] == socket.gethostname() and owner["pid"] == os.getpid()
    assert owner["start"] == _start_time(os.getpid()) and len(owner["token"]) == 32


@pytest.mark.parametrize("with_start", [True, False], ids=["pid+start", "old lock, pid only"])
def test_running_owner_keeps_its_lock(tmp_path, other_process, with_start):
    pid, start = other_process
    store = tmp_path / "s.zarr"
    write_lock(store, pid=pid, **({"start": start} if with_start else {}))
    with pytest.raises(StoreLocked, match=f"locked by another build \\(host .*, pid {pid}\\)"):
        StoreLock(store).__enter__()
    with pytest.raises(StoreLocked, match=f"still running \\(pid {pid} on this host\\).*`kill -INT {pid}`"):
        unlock(store)
    assert (store / ".lock").exists()


@needs_proc
def test_reused_pid_does_not_keep_a_dead_builds_lock(tmp_path, other_process):
    pid, start = other_process  # the pid of a dead build, now given to another process
    store = tmp_path / "s.zarr"
    write_lock(store, pid=pid, start=start - 1)
    with StoreLock(store) as lock:
        assert json.loads((store / ".lock").read_text())["token"] == lock.owner["token"]
    write_lock(store, pid=pid, start=start - 1)
    assert unlock(store)["pid"] == pid and not (store / ".lock").exists()


def test_unlock_removes_the_lock_of_a_gone_build(tmp_path):
    store = tmp_path / "s.zarr"
    assert unlock(store) is None
    write_lock(store, pid=999_999_999, start=5)
    assert unlock(store)["pid"] == 999_999_999 and not (store / ".lock").exists()


@pytest.mark.parametrize("owner", [{"host": "elsewhere", "pid": 12}, {"host": None}], ids=["other host", "no owner"])
def test_unlock_of_an_owner_this_host_cannot_check_needs_force(tmp_path, owner):
    store = tmp_path / "s.zarr"
    write_lock(store, **owner)
    with pytest.raises(StoreLocked, match="cannot check.*simgen unlock --force"):
        unlock(store)
    assert (store / ".lock").exists()
    assert unlock(store, force=True)["host"] == owner["host"] and not (store / ".lock").exists()


def test_unlock_refuses_a_lock_this_process_holds(tmp_path):
    with StoreLock(tmp_path / "s.zarr"):
        with pytest.raises(StoreLocked, match="still running"):
            unlock(tmp_path / "s.zarr")
