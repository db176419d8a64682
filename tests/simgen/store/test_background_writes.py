"""Chunk writes in the background: a failed or lost write is reported or redone, never counted as done."""

from __future__ import annotations

import errno
import threading

import pytest
import zarr
from distributed import LocalCluster

import simgen.store.worker as worker
from simgen.store.inspect import store_status
from simgen.store.runner import BuildFailed, build
from simgen.store.worker import BackgroundWriter


def test_a_failed_write_is_reported_by_flush_not_by_the_next_submit():
    writer, written, release = BackgroundWriter(), [], threading.Event()

    def write(key: str, fail: bool) -> None:
        release.wait()
        written.append(key)
        if fail:
            raise OSError(errno.ENOSPC, "No space left on device")

    writer.submit("s/0", write, "s/0", True)
    assert written == []  # submit returned before the write ran
    release.set()
    writer.submit("s/1", write, "s/1", False)  # waits for s/0 (one write in flight), does not raise its error
    assert written[0] == "s/0"
    assert writer.flush() == [("s/0", "OSError(28, 'No space left on device')")]
    assert written == ["s/0", "s/1"]
    assert writer.flush() == []


@pytest.fixture
def in_process_cluster():
    """Workers as threads of this process, so that a monkeypatched ``write_chunk`` is theirs."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        yield cluster.scheduler_address


def _failing_writes(monkeypatch, times: int) -> dict:
    """Make the write of chunk 1 of lv-scar-apex fail ``times`` times (after its task has returned)."""
    real, calls = worker.write_chunk, {"failed": 0}

    def flaky(store, subject_id, chunk, *args):
        if (subject_id, chunk) == ("lv-scar-apex", 1) and calls["failed"] < times:
            calls["failed"] += 1
            raise OSError(errno.EIO, "Input/output error")
        real(store, subject_id, chunk, *args)

    monkeypatch.setattr(worker, "write_chunk", flaky)
    return calls


def test_a_failed_background_write_is_simulated_again(
    tmp_path, monkeypatch, tiny_spec, reference_store, store_bytes, in_process_cluster
):
    calls = _failing_writes(monkeypatch, times=1)
    store = tmp_path / "s.zarr"
    build(tiny_spec(), store, scheduler=in_process_cluster)
    assert calls["failed"] == 1
    assert store_bytes(store) == store_bytes(reference_store)


def test_a_write_that_keeps_failing_is_named_and_the_rest_kept(tmp_path, monkeypatch, tiny_spec, in_process_cluster):
    _failing_writes(monkeypatch, times=2)
    store = tmp_path / "s.zarr"
    with pytest.raises(BuildFailed, match=r"lv-scar-apex/1: OSError\(5, 'Input/output error'\)") as info:
        build(tiny_spec(), store, scheduler=in_process_cluster)
    assert "lv-healthy" not in str(info.value)
    assert {s.subject_id: s.chunks_done for s in store_status(store)} == {"lv-healthy": 2, "lv-scar-apex": 1}
    assert zarr.open_group(str(store), mode="r").attrs["complete"] is False
