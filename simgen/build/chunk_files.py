"""How workers write chunk files: with direct I/O, in pieces, and uncompressed chunks without Zarr's copies.

Zarr's :class:`~zarr.storage.LocalStore` hands a whole encoded chunk to one
buffered ``write()``. A dataset build writes gigabytes that nothing reads
back soon, so the page cache only costs: on the Linux VMs this project is
measured on (kernel 6.18, ext4, virtio disk, memory handed back to the host
when freed), every new page-cache page is first-touch memory at ~2.6 ms/MB,
and a 64-site chunk of the default 2,000-node LV (29 MB) took 75-80 ms to
write buffered (spikes to 0.5 s under writeback), against 17-22 ms with
``O_DIRECT`` (the disk's ~1.5 GB/s, the CPU mostly idle). So each file is
written with ``O_DIRECT`` from a page-aligned staging buffer, 4 MiB per
``write()``, the last piece padded to the block size and the file truncated
to its length; where direct I/O is refused (tmpfs, some network file
systems, no ``O_DIRECT`` on the platform) the same pieces go through the
page cache, as do small files (done flags, metadata). The files, their
names and the atomic write (a ``*.partial`` temporary renamed into place,
which :func:`simgen.build.location.remove_partials` cleans up after a kill)
are Zarr's, so any reader opens the store as usual.

Zarr's encoding of an uncompressed, checksummed chunk (``bytes`` +
``crc32c`` codecs) copies the 29 MB twice (the checksum is appended with
``np.append``, then the staging copy above). :func:`write_checksummed` writes
the same file from the values' own memory instead: checksum computed in
place, whole blocks written straight from a page-aligned array (the solver
allocates its output so), only the last partial block and the checksum
staged. :func:`chunk_file` says when a chunk can be written so.
"""

from __future__ import annotations

import asyncio
import errno
import mmap
import os
import threading
import uuid
from pathlib import Path

import crc32c
import numpy as np
import zarr
from numpy.typing import NDArray
from zarr.abc.store import Store
from zarr.codecs import BytesCodec, Crc32cCodec
from zarr.core.buffer import Buffer
from zarr.storage import LocalStore

from simgen.build.location import is_url

__all__ = ["PIECE_BYTES", "DirectLocalStore", "writable_store", "write_in_pieces", "write_checksummed", "chunk_file"]

#: Bytes per ``write()`` call (direct I/O rounds it up to :data:`ALIGN`).
PIECE_BYTES = 4 << 20
#: Offsets, lengths and buffer addresses of direct I/O are multiples of this (a page; any block size divides it).
ALIGN = 4096
#: Files smaller than this go through the page cache: a direct write waits for the device (done flags, metadata).
DIRECT_MIN_BYTES = 64 << 10
_O_DIRECT = getattr(os, "O_DIRECT", 0)
_local = threading.local()
#: The chunk codecs whose files :func:`write_checksummed` writes: raw little-endian values, then their CRC32C
#: (Zarr leaves the byte order out for one-byte types).
_CHECKSUMMED = ((BytesCodec(endian="little"), Crc32cCodec()), (BytesCodec(endian=None), Crc32cCodec()))


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


def write_checksummed(path: Path, data: NDArray, fill: NDArray | None = None) -> None:
    """Write the chunk file Zarr's ``bytes`` + ``crc32c`` codecs make of ``data`` (then ``fill``, if given).

    The values' bytes (C order, as stored: a little-endian dtype), then the
    CRC32C of them, little-endian - with no copy of ``data`` when it starts
    on a page (:func:`_write_direct`). ``fill`` completes a chunk that ``data``
    covers only the start of. Written as :func:`write_in_pieces` writes.
    """
    arrays = [np.ascontiguousarray(a) for a in (data, fill) if a is not None]
    if any(a.dtype.byteorder == ">" for a in arrays):
        raise ValueError("chunk values must be little-endian (as the bytes codec stores them)")
    pieces = [a.reshape(-1).view(np.uint8) for a in arrays]
    crc = 0
    for piece in pieces:  # the crc32c package: 1.1 ms for 29 MB, Zarr's google-crc32c 4.3 ms (measured)
        crc = crc32c.crc32c(piece, crc)
    _replace(path, [*pieces, np.array([crc], "<u4").view(np.uint8)], exclusive=False)


def chunk_file(array: zarr.Array, coords: tuple[int, ...]) -> Path | None:
    """The file of chunk ``coords`` of ``array`` if :func:`write_checksummed` can write it, else ``None``.

    It can when the array lives in a writable :class:`DirectLocalStore` and its
    chunks are encoded by exactly the ``bytes`` (little-endian) + ``crc32c``
    codecs (no compressor, no sharding).
    """
    store = array.store_path.store
    if not isinstance(store, DirectLocalStore) or store.read_only or tuple(array.metadata.codecs) not in _CHECKSUMMED:
        return None
    key = array.metadata.encode_chunk_key(coords)
    return store.root / array.store_path.path / key if array.store_path.path else store.root / key


class DirectLocalStore(LocalStore):
    """:class:`~zarr.storage.LocalStore` whose writes go through :func:`write_in_pieces`."""

    async def _set(self, key: str, value: Buffer, exclusive: bool = False) -> None:
        if not self._is_open:
            await self._open()
        self._check_writable()
        if not isinstance(value, Buffer):
            raise TypeError(f"store value must be a zarr Buffer, got {type(value).__name__}")
        await asyncio.to_thread(write_in_pieces, self.root / key, value, exclusive)


def writable_store(store: str) -> Store | str:
    """What a worker opens to write: a :class:`DirectLocalStore` for a local folder, else the URL itself."""
    return store if is_url(store) else DirectLocalStore(store)
