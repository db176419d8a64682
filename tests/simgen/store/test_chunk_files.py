"""Workers' local store: Zarr's own files, written with direct I/O or buffered, atomic and exclusive as Zarr's;
checksummed chunk files written without Zarr, byte for byte the same."""

from __future__ import annotations

import errno
import os

import google_crc32c
import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec

import simgen.store.chunk_files as chunk_files
from shared.zarr_format import default_buffer_prototype, sync
from simgen.solver.simulate import page_aligned_empty
from simgen.store.chunk_files import (
    DirectLocalStore,
    chunk_file,
    writable_store,
    write_checksummed,
    write_in_pieces,
    write_rows,
)


def _buffer(data: bytes):
    return default_buffer_prototype().buffer.from_bytes(data)


@pytest.fixture(params=["direct", "buffered"])
def io_mode(request, monkeypatch):
    """Run a test through direct I/O (where this file system takes it) and through the page cache."""
    if request.param == "buffered":
        monkeypatch.setattr(chunk_files, "_O_DIRECT", 0)
    return request.param


def test_multi_piece_chunks_are_zarrs_own_files_and_read_back_bitwise(tmp_path, monkeypatch, io_mode):
    monkeypatch.setattr(chunk_files, "PIECE_BYTES", 4096)  # every chunk below is ~28 pieces, the last one partial
    u = np.random.default_rng(0).random((3, 7, 4_000), dtype=np.float32)
    for name in ("plain.zarr", "ours.zarr"):
        zarr.create_array(str(tmp_path / name), shape=u.shape, chunks=(1, 7, 4_000), dtype="f4", compressors=None)
    zarr.open_array(str(tmp_path / "plain.zarr"), mode="r+")[...] = u
    zarr.open_array(DirectLocalStore(tmp_path / "ours.zarr"), mode="r+")[...] = u
    assert np.array_equal(zarr.open_array(str(tmp_path / "ours.zarr"), mode="r")[...], u)
    chunks = sorted(p.relative_to(tmp_path / "plain.zarr") for p in (tmp_path / "plain.zarr" / "c").rglob("*"))
    assert len([c for c in chunks if (tmp_path / "plain.zarr" / c).is_file()]) == 3
    for c in chunks:  # same names, same lengths (the padded direct writes are cut back), same bytes
        ours, plain = tmp_path / "ours.zarr" / c, tmp_path / "plain.zarr" / c
        assert ours.is_file() == plain.is_file()
        if plain.is_file():
            assert ours.read_bytes() == plain.read_bytes()
    assert not list(tmp_path.rglob("*.partial"))


def test_direct_io_is_tried_first_and_a_refusal_falls_back_to_the_page_cache(tmp_path, monkeypatch):
    if not chunk_files._O_DIRECT:
        pytest.skip("no O_DIRECT on this platform")
    real_open, modes = os.open, []

    def refusing_open(path, flags, mode=0o777):
        modes.append(bool(flags & chunk_files._O_DIRECT))
        if flags & chunk_files._O_DIRECT:
            raise OSError(errno.EINVAL, "Invalid argument")  # what tmpfs and some network file systems answer
        return real_open(path, flags, mode)

    monkeypatch.setattr(chunk_files.os, "open", refusing_open)
    write_in_pieces(tmp_path / "k", _buffer(b"x" * 100_000))
    assert modes == [True, False]
    assert (tmp_path / "k").read_bytes() == b"x" * 100_000


def test_exclusive_write_refuses_an_existing_file(tmp_path, io_mode):
    store = DirectLocalStore(tmp_path)
    sync(store.set("k", _buffer(b"first")))
    sync(store.set_if_not_exists("k", _buffer(b"second")))  # Zarr's contract: a no-op, not an overwrite
    assert (tmp_path / "k").read_bytes() == b"first"
    with pytest.raises(FileExistsError):
        write_in_pieces(tmp_path / "k", _buffer(b"third"), exclusive=True)
    assert (tmp_path / "k").read_bytes() == b"first"


def test_a_write_that_fails_midway_keeps_the_old_file_and_leaves_no_partial(tmp_path, monkeypatch, io_mode):
    target = tmp_path / "c" / "0"
    write_in_pieces(target, _buffer(b"old"))
    monkeypatch.setattr(chunk_files, "PIECE_BYTES", 4096)
    calls = {"n": 0}
    real_write_all = chunk_files._write_all

    def failing_write_all(fd, data):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_write_all(fd, data)

    monkeypatch.setattr(chunk_files, "_write_all", failing_write_all)
    with pytest.raises(OSError, match="No space left"):
        write_in_pieces(target, _buffer(b"new bytes, several pieces" * 1_000))
    assert calls["n"] == 2
    assert target.read_bytes() == b"old"
    assert not list(tmp_path.rglob("*.partial"))


def test_urls_stay_urls():
    assert writable_store("s3://bucket/name.zarr") == "s3://bucket/name.zarr"
    assert isinstance(writable_store("/data/name.zarr"), DirectLocalStore)


@pytest.mark.parametrize("aligned", [True, False], ids=["page-aligned", "unaligned"])
@pytest.mark.parametrize(
    "sites, sharded",
    [(4, False), (4, True), (3, True)],
    ids=["whole-chunk", "whole-shard", "last-shard"],
)
def test_written_files_are_byte_for_byte_zarrs(tmp_path, monkeypatch, io_mode, aligned, sites, sharded):
    monkeypatch.setattr(chunk_files, "PIECE_BYTES", 3 * 4096)  # several pieces, straight from memory and staged
    shape = (4 + sites, 4, 1_101)  # files of 4 sites, 70,464 bytes: not a whole number of blocks; file 1 written
    values = page_aligned_empty((sites + 1, *shape[1:]), np.float32)
    values[...] = np.random.default_rng(1).random(values.shape, dtype=np.float32)
    values = values[:sites] if aligned else values[1:]
    assert (values.ctypes.data % chunk_files.ALIGN == 0) is aligned
    layout = {"chunks": (1, *shape[1:]), "shards": (4, *shape[1:])} if sharded else {"chunks": (4, *shape[1:])}
    for name in ("plain.zarr", "ours.zarr"):
        zarr.create_array(
            str(tmp_path / name), shape=shape, dtype="f4", fill_value=np.nan, compressors=(Crc32cCodec(),), **layout
        )
    zarr.open_array(str(tmp_path / "plain.zarr"), mode="r+")[4 : 4 + sites] = values
    ours = zarr.open_array(DirectLocalStore(tmp_path / "ours.zarr"), mode="r+")
    assert chunk_file(ours, (1, 0, 0)) == tmp_path / "ours.zarr" / "c" / "1" / "0" / "0"
    assert write_rows(ours, 4, values)
    assert (tmp_path / "ours.zarr/c/1/0/0").read_bytes() == (tmp_path / "plain.zarr/c/1/0/0").read_bytes()
    assert np.array_equal(zarr.open_array(str(tmp_path / "ours.zarr"), mode="r")[4 : 4 + sites], values)
    assert not list(tmp_path.rglob("*.partial"))


def test_only_whole_files_are_written_and_the_rest_left_to_zarr(tmp_path):
    ours = zarr.create_array(
        DirectLocalStore(tmp_path / "s.zarr"), shape=(7, 8), chunks=(2, 8), dtype="f4", compressors=(Crc32cCodec(),)
    )
    rows = np.ones((2, 8), np.float32)
    assert not write_rows(ours, 1, rows)  # not at a chunk's start
    assert not write_rows(ours, 0, rows[:1])  # part of a chunk
    assert not write_rows(ours, 6, rows[:1])  # the last chunk: Zarr stores its fill past the end
    assert not write_rows(ours, 0, np.ones((2, 4), np.float32))  # part of the other dimension
    assert not list(tmp_path.rglob("c/*"))
    assert write_rows(ours, 2, rows) and (tmp_path / "s.zarr/c/1/0").is_file()


def test_only_uncompressed_checksummed_arrays_in_a_direct_store_get_chunk_files(tmp_path):
    def array(name, store=None, dtype="f4", chunks=(2, 8), **kw):
        return zarr.create_array(
            store or DirectLocalStore(tmp_path / name), shape=(4, 8), chunks=chunks, dtype=dtype, **kw
        )

    assert chunk_file(array("flags.zarr", dtype="u1", compressors=(Crc32cCodec(),)), (1, 0)) is not None
    assert chunk_file(array("f4.zarr", compressors=(Crc32cCodec(),)), (1, 0)) == tmp_path / "f4.zarr/c/1/0"
    assert chunk_file(array("blosc.zarr", compressors=(BloscCodec(cname="lz4"), Crc32cCodec())), (1, 0)) is None
    assert chunk_file(array("plain.zarr", compressors=None), (1, 0)) is None  # no checksum
    assert chunk_file(array("s", str(tmp_path / "zarrs-own.zarr"), compressors=(Crc32cCodec(),)), (1, 0)) is None
    assert chunk_file(array("sharded.zarr", chunks=(1, 8), shards=(2, 8)), (1, 0)) is None  # no checksum
    rows = array("rows.zarr", chunks=(1, 8), shards=(2, 8), compressors=(Crc32cCodec(),))
    assert chunk_file(rows, (1, 0)) == tmp_path / "rows.zarr/c/1/0"
    tiles = array("tiles.zarr", chunks=(1, 4), shards=(2, 8), compressors=(Crc32cCodec(),))
    assert chunk_file(tiles, (1, 0)) is None  # inner chunks of part of a row
    read_only = zarr.open_array(DirectLocalStore(tmp_path / "f4.zarr", read_only=True), mode="r")
    assert chunk_file(read_only, (1, 0)) is None  # Zarr refuses the write


def test_big_endian_values_are_refused(tmp_path):
    with pytest.raises(ValueError, match="little-endian"):
        write_checksummed(tmp_path / "c", np.zeros(4, ">f4"))
    assert not list(tmp_path.iterdir())


def test_small_files_go_through_the_page_cache(tmp_path, monkeypatch):
    real_open, direct = os.open, []

    def recording_open(path, flags, mode=0o777):
        direct.append(bool(flags & chunk_files._O_DIRECT))
        return real_open(path, flags, mode)

    monkeypatch.setattr(chunk_files.os, "open", recording_open)
    write_checksummed(tmp_path / "done", np.ones(1, np.uint8))  # a done flag: 5 bytes
    assert direct == [False]
    assert (tmp_path / "done").read_bytes() == b"\x01" + np.array([google_crc32c.value(b"\x01")], "<u4").tobytes()
