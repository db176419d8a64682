"""Workers' local store: files written in pieces, read back by plain Zarr, atomic and exclusive as Zarr's."""

from __future__ import annotations

import numpy as np
import pytest
import zarr
from zarr.core.buffer import default_buffer_prototype
from zarr.core.sync import sync

import simgen.build.chunk_files as chunk_files
from simgen.build.chunk_files import PiecewiseLocalStore, writable_store, write_in_pieces


def _buffer(data: bytes):
    return default_buffer_prototype().buffer.from_bytes(data)


def test_multi_piece_chunks_read_back_bitwise_by_plain_zarr(tmp_path, monkeypatch):
    monkeypatch.setattr(chunk_files, "PIECE_BYTES", 4096)  # every chunk below is ~28 pieces
    u = np.random.default_rng(0).random((3, 7, 4_000), dtype=np.float32)
    zarr.create_array(str(tmp_path / "a.zarr"), shape=u.shape, chunks=(1, 7, 4_000), dtype="f4", compressors=None)
    written = zarr.open_array(PiecewiseLocalStore(tmp_path / "a.zarr"), mode="r+")
    written[...] = u
    assert np.array_equal(zarr.open_array(str(tmp_path / "a.zarr"), mode="r")[...], u)
    assert not list(tmp_path.rglob("*.partial"))


def test_exclusive_write_refuses_an_existing_file(tmp_path):
    store = PiecewiseLocalStore(tmp_path)
    sync(store.set("k", _buffer(b"first")))
    sync(store.set_if_not_exists("k", _buffer(b"second")))  # Zarr's contract: a no-op, not an overwrite
    assert (tmp_path / "k").read_bytes() == b"first"
    with pytest.raises(FileExistsError):
        write_in_pieces(tmp_path / "k", _buffer(b"third"), exclusive=True)
    assert (tmp_path / "k").read_bytes() == b"first"


def test_a_write_that_fails_midway_keeps_the_old_file_and_leaves_no_partial(tmp_path, monkeypatch):
    target = tmp_path / "c" / "0"
    write_in_pieces(target, _buffer(b"old"))
    monkeypatch.setattr(chunk_files, "PIECE_BYTES", 4)
    calls = {"n": 0}
    real_open = open

    class Failing:
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            calls["n"] += 1
            if calls["n"] == 2:
                raise OSError("disk full")
            return self.f.write(data)

    monkeypatch.setattr(chunk_files, "open", lambda p, mode: Failing(real_open(p, mode)), raising=False)
    with pytest.raises(OSError, match="disk full"):
        write_in_pieces(target, _buffer(b"new bytes, several pieces"))
    assert target.read_bytes() == b"old"
    assert not list(tmp_path.rglob("*.partial"))


def test_urls_stay_urls():
    assert writable_store("s3://bucket/name.zarr") == "s3://bucket/name.zarr"
    assert isinstance(writable_store("/data/name.zarr"), PiecewiseLocalStore)
