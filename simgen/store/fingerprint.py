"""Chunk fingerprints: a cheap hash tying a chunk's data to its place in the store.

The CRC32C checksum at the end of every chunk file proves that the file is
intact, not that it lies where it belongs: a chunk file copied over another
subject's chunk (or another chunk of the same subject) decodes fine, and so
do its moments when they are copied with it. A task therefore stores, with its
chunk's moments, a fingerprint of the chunk's place and content, and
``simgen verify`` and every reader (:mod:`shared.integrity`) recompute it from
the chunk they read at that place. The function lives in :mod:`shared.integrity`,
which the learner reads through too.
"""

from __future__ import annotations

from shared.integrity import chunk_fingerprint

__all__ = ["chunk_fingerprint"]
