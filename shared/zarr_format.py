"""The store's byte format where it goes beyond Zarr's public API: every such use, and the shard layout written
and read by hand, in one module.

What is here, and why:

- Zarr's private modules: :func:`sync` (run a store's coroutines from
  synchronous code, on Zarr's own event loop, which fsspec stores need),
  :class:`GroupMetadata` and :class:`ArrayV3Metadata` (the ``zarr.json`` a
  layout writes and a check compares, built in memory), :func:`metadata_file`
  (their bytes), :func:`store_of` and :func:`group_with_attrs` (a store
  opened from a location without reading its root metadata).
- The overridden private method :meth:`zarr.storage.LocalStore._set`
  (:class:`FileWriterStore`): every file of a local store written by a
  function of ours (direct I/O, :mod:`simgen.store.chunk_files`).
- The shard layout of ``u`` and ``activation`` (:func:`row_shard`): one-row
  inner chunks of raw little-endian values and their CRC32C, the index of
  ``(offset, length)`` little-endian uint64 pairs (all ones: absent) and its
  CRC32C at the end. :func:`shard_index` writes it
  (:func:`simgen.store.chunk_files.write_shard`), :func:`read_shard_index`
  reads it back (:class:`shared.integrity.SubjectReader` checks chunks from
  their stored CRCs without decoding them).

pyproject.toml bounds zarr to the minor release ``tests/test_zarr_format.py``
passes on; ``make contracts`` runs that test (and numba's,
:mod:`simgen.solver.numba_internals`) against the newest releases on PyPI, and
each failing check names the API that changed. Modules that use this one:
``shared/integrity.py``, ``simgen/store/{structure,layout,repair,chunk_files}.py``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import crc32c
import numpy as np
import zarr
from numpy.typing import NDArray
from zarr.abc.store import RangeByteRequest, Store, SuffixByteRequest
from zarr.codecs import BytesCodec, Crc32cCodec, ShardingCodec, ShardingCodecIndexLocation
from zarr.core.buffer import Buffer, default_buffer_prototype
from zarr.core.group import AsyncGroup, GroupMetadata
from zarr.core.metadata import ArrayV3Metadata
from zarr.core.sync import sync
from zarr.storage import LocalStore
from zarr.storage._common import make_store_path

__all__ = [
    "ABSENT",
    "CHECKSUMMED",
    "ArrayV3Metadata",
    "Buffer",
    "FileWriterStore",
    "GroupMetadata",
    "RangeByteRequest",
    "Store",
    "SuffixByteRequest",
    "crc_bytes",
    "default_buffer_prototype",
    "group_with_attrs",
    "index_bytes",
    "metadata_file",
    "read_shard_index",
    "row_shard",
    "shard_index",
    "store_of",
    "sync",
]

#: Chunk codecs of the files written by hand (and of a shard's inner chunks and index): raw little-endian
#: values, then their CRC32C (Zarr leaves the byte order out for one-byte types).
CHECKSUMMED = ((BytesCodec(endian="little"), Crc32cCodec()), (BytesCodec(endian=None), Crc32cCodec()))
#: Offset and length of an inner chunk a shard does not store.
ABSENT = 2**64 - 1
#: Bytes of one index entry (offset, length) and of a CRC32C.
_ENTRY, _CRC = 16, 4


def metadata_file(metadata: ArrayV3Metadata | GroupMetadata) -> Buffer:
    """The ``zarr.json`` bytes of ``metadata`` (an array's or a group's)."""
    return metadata.to_buffer_dict(default_buffer_prototype())["zarr.json"]


def store_of(location: str) -> Store:
    """The store at ``location`` (a folder or an fsspec URL), opened read-only without reading any metadata."""
    return sync(make_store_path(location, mode="r")).store


def group_with_attrs(location: str, attrs: dict) -> zarr.Group:
    """The root group of the store at ``location`` as if its ``zarr.json`` held ``attrs`` (what a repair will
    write), whatever it holds now."""
    return zarr.Group(AsyncGroup(GroupMetadata(attributes=attrs), sync(make_store_path(location, mode="r"))))


class FileWriterStore(LocalStore):
    """A :class:`~zarr.storage.LocalStore` whose every file is written by :attr:`write_file` ``(path, value,
    exclusive)``, ``exclusive`` as Zarr's ``set_if_not_exists`` requires (Zarr's private ``_set`` overridden)."""

    write_file: Callable[[Path, Buffer, bool], None]

    async def _set(self, key: str, value: Buffer, exclusive: bool = False) -> None:
        if not self._is_open:
            await self._open()
        self._check_writable()
        if not isinstance(value, Buffer):
            raise TypeError(f"store value must be a zarr Buffer, got {type(value).__name__}")
        await asyncio.to_thread(type(self).write_file, self.root / key, value, exclusive)


def row_shard(array: zarr.Array) -> bool:
    """Whether ``array`` is sharded into inner chunks of one row across all other dimensions, each raw values
    and their CRC32C, the index checksummed at the end: the layout written and read by hand."""
    codecs = tuple(array.metadata.codecs)
    if len(codecs) != 1 or not isinstance(codecs[0], ShardingCodec):
        return False
    codec = codecs[0]
    return (
        codec.chunk_shape == (1, *array.shape[1:])
        and tuple(codec.codecs) in CHECKSUMMED
        and tuple(codec.index_codecs) == CHECKSUMMED[0]
        and codec.index_location == ShardingCodecIndexLocation.end
    )


def crc_bytes(piece: NDArray[np.uint8] | bytes) -> NDArray[np.uint8]:
    """The CRC32C of ``piece``, little-endian, as Zarr's ``crc32c`` codec appends it."""
    return np.array([crc32c.crc32c(piece)], "<u4").view(np.uint8)


def shard_index(stored: int, shard_rows: int, row_bytes: int) -> NDArray[np.uint8]:
    """The index (and its CRC32C) of a shard of ``shard_rows`` inner chunks whose first ``stored`` are stored
    one after another, ``row_bytes`` each (their CRC32C included); the rest are absent."""
    index = np.full((shard_rows, 2), ABSENT, "<u8")
    index[:stored, 0] = np.arange(stored) * row_bytes
    index[:stored, 1] = row_bytes
    index_bytes = index.reshape(-1).view(np.uint8)
    return np.concatenate([index_bytes, crc_bytes(index_bytes)])


def index_bytes(shard_rows: int) -> int:
    """Bytes of a shard's index of ``shard_rows`` inner chunks, its CRC32C included."""
    return shard_rows * _ENTRY + _CRC


def read_shard_index(raw: bytes, shard_rows: int) -> NDArray[np.uint64] | None:
    """The ``(offset, length)`` rows (``shard_rows``, 2) of a shard's index from its last bytes ``raw``
    (:func:`index_bytes`); ``None`` when they are short or fail their CRC32C."""
    if len(raw) < index_bytes(shard_rows) or crc32c.crc32c(raw[:-_CRC]) != int.from_bytes(raw[-_CRC:], "little"):
        return None
    return np.frombuffer(raw[:-_CRC], "<u8").reshape(-1, 2)
