"""How workers write chunk files: with direct I/O, in pieces, and uncompressed chunks without Zarr's copies.

Zarr's :class:`~zarr.storage.LocalStore` hands a whole encoded chunk to one
buffered ``write()``. A dataset build writes gigabytes that nothing reads
back soon, so the page cache only costs: on a VM that hands freed memory back
to its host every new page-cache page is first-touch memory, and writeback
stalls the writer (docs/performance.md, "Direct I/O"). So each file is
written with ``O_DIRECT`` from a page-aligned staging buffer, 4 MiB per
``write()``, the last piece padded to the block size and the file truncated
to its length; where direct I/O is refused (tmpfs, some network file
systems, no ``O_DIRECT`` on the platform) the same pieces go through the
page cache, as do small files (done flags, metadata). The files, their
names and the atomic write (a ``*.partial`` temporary renamed into place,
which :func:`simgen.store.location.remove_partials` cleans up after a kill)
are Zarr's, so any reader opens the store as usual.

Zarr's encoding of an uncompressed, checksummed chunk (``bytes`` +
``crc32c`` codecs) copies the data twice (the checksum is appended with
``np.append``, then the staging copy above). :func:`write_rows` writes the
same files from the values' own memory instead, checksums computed in place,
whole blocks written straight from a page-aligned array (the solver allocates
its output so), the rest staged:

- a plain chunk (``done`` flags, ``moments``): the values' bytes, then their CRC32C;
- a shard of ``u`` or ``activation`` (Zarr's ``sharding_indexed`` codec, one
  inner chunk per row along the first axis): each row's bytes and CRC32C, then
  the index (offset and length of each inner chunk, all ones for a row past the
  array's end, which Zarr does not store) and its CRC32C. The rows after the
  first start inside a block, so they go through the staging buffer: one copy.
"""

from __future__ import annotations

import errno
import mmap
import os
import threading
import uuid
from pathlib import Path

import numpy as np
import zarr
from numpy.typing import NDArray

from shared.zarr_format import CHECKSUMMED, Buffer, FileWriterStore, Store, crc_bytes, row_shard, shard_index
from simgen.store.location import is_url

__all__ = [
    "PIECE_BYTES",
    "DirectLocalStore",
    "writable_store",
    "write_in_pieces",
    "write_checksummed",
    "write_shard",
    "chunk_file",
    "write_rows",
]

#: Bytes per ``write()`` call (direct I/O rounds it up to :data:`ALIGN`).
PIECE_BYTES = 4 << 20
#: Offsets, lengths and buffer addresses of direct I/O are multiples of this (a page; any block size divides it).
ALIGN = 4096
#: Files smaller than this go through the page cache: a direct write waits for the device (done flags, metadata).
DIRECT_MIN_BYTES = 64 << 10
_O_DIRECT = getattr(os, "O_DIRECT", 0)
_local = threading.local()


def _staging(size: int) -> NDArray[np.uint8]:
    """This thread's page-aligned buffer of ``size`` bytes for direct writes (kept: fresh memory costs here)."""
    stage = getattr(_local, "stage", None)
    if stage is None or len(stage) != size:
        stage = _local.stage = np.frombuffer(mmap.mmap(-1, size), np.uint8)
    return stage


def _write_all(fd: int, data: NDArray[np.uint8]) -> None:
    while len(data):
        data = data[os.write(fd, data) :]


def _write_direct(fd: int, pieces: list[NDArray[np.uint8]]) -> int:
    """Write ``pieces`` one after the other with direct I/O; returns their length (the file is padded past it).

    A piece that starts on a page at a block boundary of the file goes out
    straight from its memory (whole blocks, no copy); the rest is gathered in
    this thread's staging buffer, whose last fill is padded to whole blocks.
    """
    step = -(-PIECE_BYTES // ALIGN) * ALIGN
    stage, fill, total = _staging(step), 0, 0
    for piece in pieces:
        total += len(piece)
        if fill == 0 and piece.ctypes.data % ALIGN == 0:
            whole = len(piece) - len(piece) % ALIGN
            for start in range(0, whole, step):
                _write_all(fd, piece[start : min(start + step, whole)])
            piece = piece[whole:]
        while len(piece):
            n = min(len(piece), step - fill)
            stage[fill : fill + n] = piece[:n]
            fill, piece = fill + n, piece[n:]
            if fill == step:
                _write_all(fd, stage)
                fill = 0
    if fill:
        _write_all(fd, stage[: -(-fill // ALIGN) * ALIGN])
    return total


def _write_file(path: Path, pieces: list[NDArray[np.uint8]], direct: bool) -> None:
    """Write the concatenated ``pieces`` to a new file ``path``; ``direct`` bypasses the page cache."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | (_O_DIRECT if direct else 0), 0o644)
    try:
        if direct:
            os.ftruncate(fd, _write_direct(fd, pieces))  # cut the padding of the last block off
        else:
            for piece in pieces:
                for start in range(0, len(piece), PIECE_BYTES):
                    _write_all(fd, piece[start : start + PIECE_BYTES])
    finally:
        os.close(fd)


def _replace(path: Path, pieces: list[NDArray[np.uint8]], exclusive: bool) -> None:
    """Write the concatenated ``pieces`` to ``path`` through a ``*.partial`` temporary renamed into place.

    Direct I/O where the file system takes it and the file is not small, else
    buffered. ``exclusive`` refuses an existing ``path`` (``FileExistsError``).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{uuid.uuid4().hex}.partial")
    direct = bool(_O_DIRECT) and sum(len(piece) for piece in pieces) >= DIRECT_MIN_BYTES
    try:
        try:
            _write_file(partial, pieces, direct)
        except OSError as e:  # direct I/O refused by this file system: the page cache it is
            if not (direct and e.errno == errno.EINVAL):
                raise
            _write_file(partial, pieces, direct=False)
        if exclusive:
            os.link(partial, path)  # fails if path exists
            partial.unlink()
        else:
            os.replace(partial, path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def write_in_pieces(path: Path, value: Buffer, exclusive: bool = False) -> None:
    """Write Zarr's encoded ``value`` to ``path`` as :func:`_replace` does (``exclusive`` as Zarr's
    ``set_if_not_exists`` requires)."""
    _replace(path, [value.as_numpy_array().view(np.uint8).reshape(-1)], exclusive)


def _bytes(data: NDArray) -> NDArray[np.uint8]:
    """The bytes of ``data`` in C order (a view where it is contiguous); refuses big-endian values."""
    data = np.ascontiguousarray(data)
    if data.dtype.byteorder == ">":
        raise ValueError("chunk values must be little-endian (as the bytes codec stores them)")
    return data.reshape(-1).view(np.uint8)


def write_checksummed(path: Path, data: NDArray) -> None:
    """Write the chunk file Zarr's ``bytes`` + ``crc32c`` codecs make of ``data``: its bytes, then their CRC32C.

    With no copy of ``data`` when it starts on a page (:func:`_write_direct`);
    written as :func:`write_in_pieces` writes.
    """
    piece = _bytes(data)
    _replace(path, [piece, crc_bytes(piece)], exclusive=False)


def write_shard(path: Path, rows: NDArray, shard_rows: int) -> None:
    """Write the shard file of ``rows``: inner chunks of one row each, ``bytes`` + ``crc32c``, index at the end.

    ``shard_rows`` inner chunks make a shard; the first ``len(rows)`` are
    stored, the rest (past the array's end) are absent from the index, as Zarr
    writes them (:func:`shared.zarr_format.shard_index`).
    """
    flat = _bytes(rows).reshape(len(rows), -1)
    pieces = [piece for row in flat for piece in (row, crc_bytes(row))]
    _replace(path, [*pieces, shard_index(len(rows), shard_rows, flat.shape[1] + 4)], exclusive=False)


def _file_kind(array: zarr.Array) -> str | None:
    """``"chunk"`` or ``"shard"``: which file :func:`write_rows` writes for ``array``; ``None``: Zarr writes."""
    store = array.store_path.store
    if not isinstance(store, DirectLocalStore) or store.read_only:
        return None
    if tuple(array.metadata.codecs) in CHECKSUMMED:
        return "chunk"
    return "shard" if row_shard(array) else None


def chunk_file(array: zarr.Array, coords: tuple[int, ...]) -> Path | None:
    """The file of chunk ``coords`` of ``array`` (a shard, for a sharded array) if :func:`write_rows` writes it.

    It does when the array lives in a writable :class:`DirectLocalStore` and its
    chunks are encoded by exactly the ``bytes`` (little-endian) + ``crc32c``
    codecs, or sharded into inner chunks of one row so encoded (index
    checksummed, at the end); else ``None`` (a compressor, other sharding).
    """
    if _file_kind(array) is None:
        return None
    store, key = array.store_path.store, array.metadata.encode_chunk_key(coords)
    return store.root / array.store_path.path / key if array.store_path.path else store.root / key


def write_rows(array: zarr.Array, start: int, values: NDArray) -> bool:
    """``array[start:start + len(values)] = values`` as one file written here; ``False`` (nothing written)
    when that is not one whole file :func:`chunk_file` allows.

    Whole means: every row of one chunk, or of one shard up to the array's end,
    across the whole of the other dimensions.
    """
    kind, grid = _file_kind(array), array.shards or array.chunks
    rows = min(grid[0], array.shape[0] - start)
    whole = start % grid[0] == 0 and grid[1:] == array.shape[1:] and values.shape == (rows, *array.shape[1:])
    if kind is None or not whole or (kind == "chunk" and rows < grid[0]):  # Zarr stores a chunk's fill past the end
        return False
    file = chunk_file(array, (start // grid[0],) + (0,) * (array.ndim - 1))
    values = np.ascontiguousarray(values, np.dtype(array.dtype).newbyteorder("<"))
    if kind == "shard":
        write_shard(file, values, grid[0])
    else:
        write_checksummed(file, values)
    return True


class DirectLocalStore(FileWriterStore):
    """:class:`~zarr.storage.LocalStore` whose writes go through :func:`write_in_pieces`."""

    write_file = staticmethod(write_in_pieces)


def writable_store(store: str) -> Store | str:
    """What a worker opens to write: a :class:`DirectLocalStore` for a local folder, else the URL itself."""
    return store if is_url(store) else DirectLocalStore(store)
