"""The Zarr internals shared/zarr_format.py relies on: each check names the API it found changed.

shared/zarr_format.py holds every use of Zarr's private modules, the overridden
:meth:`zarr.storage.LocalStore._set` and the shard layout written and read by hand;
pyproject.toml bounds zarr to the minor release these checks pass on. ``make
contracts`` runs them against the newest zarr on PyPI: a failure says what to adapt
before the bound is raised.
"""

from __future__ import annotations

import inspect
import json
from collections.abc import Callable

import numpy as np
import pytest
import zarr
from zarr.codecs import BytesCodec, Crc32cCodec, ShardingCodec, ShardingCodecIndexLocation
from zarr.storage import LocalStore

import shared.zarr_format as zarr_format
import simgen.store.chunk_files as chunk_files
from shared.zarr_format import default_buffer_prototype, sync


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
    record = staticmethod(lambda path, value, exclusive=False: calls.append(exclusive))
    monkeypatch.setattr(chunk_files.DirectLocalStore, "write_file", record)
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


def _metadata_in_memory(tmp_path, monkeypatch) -> bool:
    """``GroupMetadata(attributes=)`` and an array's ``ArrayV3Metadata`` give the ``zarr.json`` Zarr writes."""
    group = zarr.open_group(tmp_path / "g.zarr", mode="w", zarr_format=3)
    group.attrs.put({"a": 1})
    written = json.loads((tmp_path / "g.zarr/zarr.json").read_text())
    made = json.loads(zarr_format.metadata_file(zarr_format.GroupMetadata(attributes={"a": 1})).to_bytes())
    array = _sharded(tmp_path)
    stored = json.loads((tmp_path / "s.zarr/zarr.json").read_text())
    return made == written and json.loads(zarr_format.metadata_file(array.metadata).to_bytes()) == stored


def _store_without_metadata(tmp_path, monkeypatch) -> bool:
    """``make_store_path(location, mode="r")`` opens a store with no ``zarr.json``; a group of given attributes
    (``AsyncGroup(GroupMetadata, store_path)``) lists its members."""
    zarr.open_group(tmp_path / "m.zarr", mode="w", zarr_format=3).create_group("meshes")
    (tmp_path / "m.zarr/zarr.json").unlink()
    store = zarr_format.store_of(str(tmp_path / "m.zarr"))
    group = zarr_format.group_with_attrs(str(tmp_path / "m.zarr"), {"spec": "x"})
    return sync(store.exists("meshes/zarr.json")) and dict(group.attrs) == {"spec": "x"} and "meshes" in group


def _byte_ranges(tmp_path, monkeypatch) -> bool:
    """``Store.get(key, prototype, byte_range=RangeByteRequest | SuffixByteRequest)``, as readers of fsspec stores
    call it."""
    (tmp_path / "r").mkdir()
    (tmp_path / "r/f").write_bytes(b"0123456789")
    store, proto = LocalStore(tmp_path / "r"), default_buffer_prototype()
    middle = sync(store.get("f", proto, byte_range=zarr_format.RangeByteRequest(2, 5))).to_bytes()
    tail = sync(store.get("f", proto, byte_range=zarr_format.SuffixByteRequest(3))).to_bytes()
    return (middle, tail) == (b"234", b"789")


def _index_read_back(tmp_path, monkeypatch) -> bool:
    """The index of Zarr's own shard reads back as :func:`read_shard_index` expects, and :func:`row_shard`
    knows Zarr's layout."""
    array = _sharded(tmp_path)
    array[0:2] = np.ones((2, 3), np.float32)
    raw = (tmp_path / "s.zarr/c/0/0").read_bytes()[-zarr_format.index_bytes(2) :]
    index = zarr_format.read_shard_index(raw, 2)
    return zarr_format.row_shard(array) and index is not None and index[:, 1].tolist() == [16, 16]


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
    "zarr.core.group.GroupMetadata, zarr.core.metadata.ArrayV3Metadata.to_buffer_dict": _metadata_in_memory,
    "zarr.storage._common.make_store_path, zarr.core.group.AsyncGroup": _store_without_metadata,
    "zarr.abc.store.RangeByteRequest / SuffixByteRequest in Store.get": _byte_ranges,
    "the shard index Zarr writes, read back": _index_read_back,
}


@pytest.mark.parametrize("api", list(CHECKS))
def test_zarr_api_the_store_format_relies_on(api, tmp_path, monkeypatch):
    try:
        ok = CHECKS[api](tmp_path, monkeypatch)
    except Exception as exc:  # an attribute or keyword gone: the same news
        ok = f"{type(exc).__name__}: {exc}"
    if ok is not True:
        pytest.fail(
            f"zarr {zarr.__version__} changed {api}, which shared/zarr_format.py relies on "
            f"({ok if isinstance(ok, str) else 'not as expected'}): adapt shared/zarr_format.py before raising "
            "the zarr bound in pyproject.toml",
            pytrace=False,
        )


def test_no_other_module_reaches_into_zarr_or_numba_internals():
    """The private APIs stay in the two modules that own them (and these contract tests)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    owners = {
        "shared/zarr_format.py": ("zarr.core", "zarr.storage._"),
        "simgen/solver/numba_internals.py": ("numba.core",),
    }
    private = [prefix for prefixes in owners.values() for prefix in prefixes]
    found = [
        str(path.relative_to(root))
        for package in ("shared", "simgen", "learner", "bench")
        for path in sorted((root / package).rglob("*.py"))
        if str(path.relative_to(root)) not in owners
        and any(f"from {p}" in text or f"import {p}" in text for p in private for text in [path.read_text()])
    ]
    assert not found, f"private zarr or numba API used outside shared/zarr_format.py and numba_internals.py: {found}"
