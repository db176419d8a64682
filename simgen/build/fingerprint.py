"""Chunk fingerprints: a cheap hash tying a chunk's data to its place in the store.

The CRC32C checksum at the end of every chunk file proves that the file is
intact, not that it lies where it belongs: a chunk file copied over another
subject's chunk (or another chunk of the same subject) decodes fine, and so
do its moments when they are copied with it. A task therefore stores, with its
chunk's moments, a fingerprint of the chunk's place and content, and
``simgen verify`` recomputes it from the chunk it reads at that place.
"""

from __future__ import annotations

import hashlib
import json

import crc32c
import numpy as np
from numpy.typing import NDArray

__all__ = ["chunk_fingerprint"]


def _crc(values: NDArray) -> int:
    """CRC32C of ``values`` as stored (C order, little-endian)."""
    data = np.ascontiguousarray(values, np.dtype(values.dtype).newbyteorder("<"))
    return crc32c.crc32c(data.reshape(-1).view(np.uint8))


def chunk_fingerprint(subject_id: str, chunk: int, start: int, stop: int, u: NDArray, activation: NDArray) -> int:
    """64-bit BLAKE2b of the chunk's place (subject, chunk index, sites ``[start, stop)``) and data.

    The data enter through the CRC32C of ``u`` and ``activation`` (about 1 ms
    for 29 MB), so the fingerprint costs a task or a verify next to nothing.
    Never 0, which the store's fill value keeps for "not written".
    """
    h = hashlib.blake2b(json.dumps([subject_id, int(chunk), int(start), int(stop)]).encode(), digest_size=8)
    h.update(np.array([_crc(u), _crc(activation)], "<u4").tobytes())
    return int.from_bytes(h.digest(), "little") or 1
