"""The Zarr internals simgen/store/chunk_files.py relies on: each check names the API it found changed.

chunk_files.py overrides :meth:`zarr.storage.LocalStore._set` and writes chunk and
shard files itself from the arrays' metadata; pyproject.toml bounds zarr to the
minor release these checks pass on. A failure here after a zarr upgrade says what
to adapt before the bound is raised.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import numpy as np
import pytest
import zarr
from zarr.codecs import BytesCodec, Crc32cCodec, ShardingCodec, ShardingCodecIndexLocation
from zarr.core.buffer import default_buffer_prototype
from zarr.core.sync import sync
from zarr.storage import LocalStore

import simgen.store.chunk_files as chunk_files


def _sharded(tmp_path) -> zarr.Array:
    return zarr.create_array(
        chunk_files.DirectLocalStore(tmp_path / "s.zarr"),
        shape=(5, 3),
        chunks=(1, 3),
        shards=(2, 3),
        dtype="f4",
        compressors=(Crc32cCodec(),),
    )


def _set_signature(tmp_path, monkeypatch) -> bool:
    return list(inspect.signature(LocalStore._set).parameters) == ["self", "key", "value", "exclusive"]


def _writes_go_through_set(tmp_path, monkeypatch) -> bool:
    """``set`` and ``set_if_not_exists`` of a LocalStore subclass end in its ``_set`` (``exclusive`` for the latter)."""
    calls = []
    monkeypatch.setattr(chunk_files, "write_in_pieces", lambda path, value, exclusive=False: calls.append(exclusive))
    store = chunk_files.DirectLocalStore(tmp_path)
    value = default_buffer_prototype().buffer.from_bytes(b"x")
    sync(store.set("a", value))
    sync(store.set_if_not_exists("b", value))
    return calls == [False, True]


def _store_internals(tmp_path, monkeypatch) -> bool:
    return all(hasattr(LocalStore(tmp_path), a) for a in ("_is_open", "_open", "_check_writable", "root", "read_only"))


def _array_metadata(tmp_path, monkeypatch) -> bool:
    a = _sharded(tmp_path)
    return (
        a.store_path.path == ""
        and isinstance(a.store_path.store, chunk_files.DirectLocalStore)
        and a.metadata.encode_chunk_key((1, 0)) == "c/1/0"
        and (a.shards, a.chunks) == ((2, 3), (1, 3))
    )


def _sharding_codec(tmp_path, monkeypatch) -> bool:
    checksummed = (BytesCodec(endian="little"), Crc32cCodec())
    expected = ShardingCodec(
        chunk_shape=(1, 3), codecs=checksummed, index_codecs=checksummed, index_location=ShardingCodecIndexLocation.end
    )
    return tuple(_sharded(tmp_path).metadata.codecs) == (expected,)


def _shard_bytes(tmp_path, monkeypatch) -> bool:
    """Zarr's own last (partial) shard is what :func:`chunk_files.write_shard` writes."""
    values = np.arange(3, dtype=np.float32)[None]
    _sharded(tmp_path)[4:5] = values
    chunk_files.write_shard(tmp_path / "ours", values, 2)
    return (tmp_path / "ours").read_bytes() == (tmp_path / "s.zarr/c/2/0").read_bytes()


CHECKS: dict[str, Callable] = {
    "LocalStore._set(self, key, value, exclusive)": _set_signature,
    "LocalStore.set / set_if_not_exists writing through LocalStore._set": _writes_go_through_set,
    "LocalStore._is_open, _open(), _check_writable(), root, read_only": _store_internals,
    "Array.store_path, Array.metadata.encode_chunk_key, Array.shards / Array.chunks": _array_metadata,
    "ShardingCodec(chunk_shape, codecs, index_codecs, index_location) of create_array(shards=...)": _sharding_codec,
    "the shard file format (inner chunks in order, then the uint64 index and its CRC32C)": _shard_bytes,
}


@pytest.mark.parametrize("api", list(CHECKS))
def test_zarr_api_chunk_files_relies_on(api, tmp_path, monkeypatch):
    try:
        ok = CHECKS[api](tmp_path, monkeypatch)
    except Exception as exc:  # an attribute or keyword gone: the same news
        ok = f"{type(exc).__name__}: {exc}"
    if ok is not True:
        pytest.fail(
            f"zarr {zarr.__version__} changed {api}, which simgen/store/chunk_files.py relies on "
            f"({ok if isinstance(ok, str) else 'not as expected'}): adapt chunk_files.py before raising "
            "the zarr bound in pyproject.toml",
            pytrace=False,
        )
