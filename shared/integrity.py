"""What a reader checks before it hands out ``u`` or ``activation``: checksums, content fingerprints, completeness.

A chunk of a subject (the sites one build task simulated, one shard file of
``u`` and one of ``activation`` in a schema-version-3 store) is handed out
only when

- its ``done`` flag is 1 (else its rows are NaN: never written);
- its shard index decodes (CRC32C) and holds every site of the chunk (a
  deleted or truncated shard file fails here instead of reading as NaN);
- its ``fingerprint`` (:func:`chunk_fingerprint`, written by the build task)
  equals the fingerprint of this place (subject, chunk, site range) and of
  the CRC32C checksums stored with the chunk's inner chunks: a shard copied
  over another subject's, or over another chunk of the same subject, fails
  here although every checksum in it is sound;
- each row read decodes (its inner chunk's CRC32C, checked by Zarr) and, for
  ``u``, holds finite values only.

The fingerprint hashes the CRC32C of the chunk's whole ``u`` and
``activation``; each inner chunk stores the CRC32C of its own row, and CRC32C
of a concatenation follows from the parts' checksums and lengths
(:func:`crc32c_combine`), so the check reads the shard index and 4 bytes per
site, never the chunk's data. Where the inner chunks are compressed their
checksums cover the compressed bytes, and the chunk is decoded whole once.

A chunk is checked once per :class:`SubjectReader`. Every failure is a
:class:`~shared.errors.DamagedData` naming the subject, the array, the site
and the file, and the repair command. ``simgen verify`` runs the same
fingerprint (:func:`chunk_fingerprint`) on every chunk.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import crc32c
import numpy as np
import zarr
from numpy.typing import ArrayLike, NDArray
from zarr.storage import LocalStore

from shared.errors import DamagedData, InputError
from shared.schema import SCHEMA_VERSION, subject_path
from shared.zarr_format import (
    ABSENT,
    RangeByteRequest,
    SuffixByteRequest,
    default_buffer_prototype,
    index_bytes,
    read_shard_index,
    row_shard,
    sync,
)

__all__ = [
    "DIGESTS",
    "array_digest",
    "read_failure",
    "array_problem",
    "read_checked",
    "chunk_fingerprint",
    "fingerprint_from_crcs",
    "crc32c_combine",
    "repair_hint",
    "SubjectReader",
]

#: Group attribute recording the SHA-256 of each small array's values (mesh arrays, tissue fields, coordinates).
DIGESTS = "digests"
#: Arrays whose values are never all fill value (0), so a missing chunk file is damage where no digest says so.
_NEVER_FILL = frozenset({"points", "cells", "times", "time_ms", "a", "D"})


def array_digest(values: ArrayLike, dtype: str | np.dtype | None = None) -> str:
    """SHA-256 (hex) of ``values`` as stored: ``dtype`` (default: their own), little-endian, C order."""
    values = np.asarray(values)
    data = np.ascontiguousarray(values, np.dtype(dtype or values.dtype).newbyteorder("<"))
    return hashlib.sha256(data.reshape(-1).view(np.uint8)).hexdigest()


def read_failure(arr: zarr.Array, coords: tuple[int, ...], exc: Exception) -> str:
    """What a failed chunk read means: a checksum mismatch or another decoding error, naming the file."""
    key = f"{arr.path}/{arr.metadata.encode_chunk_key(coords)}"
    if "checksum" in str(exc):
        return f"checksum mismatch (file {key})"
    return f"unreadable (file {key}): {type(exc).__name__}: {exc}"


def _chunk_files(arr: zarr.Array) -> list[str]:
    """The keys of every chunk file of ``arr``."""
    grid = [-(-size // chunk) for size, chunk in zip(arr.shape, arr.chunks)]
    return [f"{arr.path}/{arr.metadata.encode_chunk_key(tuple(c))}" for c in np.ndindex(*grid)]


def array_problem(arr: zarr.Array, digest: str | None) -> tuple[NDArray | None, str | None]:
    """The values of small array ``arr`` (read whole) and ``None``, or ``None`` and what is wrong with them.

    Wrong: a chunk that does not decode (checksum), values that differ from
    ``digest`` (the group's recorded :func:`array_digest`; a chunk file gone
    is named), or, with no digest recorded, a missing chunk file of an array
    whose values are never all fill value.
    """
    try:
        values = arr[...]
    except Exception as exc:  # codec errors of a corrupted or truncated file
        return None, f"{arr.basename} {read_failure(arr, (0,) * arr.ndim, exc)}"
    if digest is not None and array_digest(values) == digest:
        return values, None
    if digest is None and arr.basename not in _NEVER_FILL:
        return values, None
    files = _chunk_files(arr) if values.size else []
    missing = [key for key in files if not sync(arr.store_path.store.exists(key))]
    if missing:
        return None, f"{arr.basename} chunk file {', '.join(missing)} missing"
    if digest is not None:
        return None, f"{arr.basename} differs from its recorded digest (file {', '.join(files)})"
    return values, None


def read_checked(group: zarr.Group, name: str, store: str, where: str) -> NDArray:
    """Array ``name`` of ``group`` whole, checked by :func:`array_problem`; ``where``: ``mesh <id>`` or
    ``subject <id>``. Raises :class:`~shared.errors.DamagedData` naming store, group, array and file."""
    values, problem = array_problem(group[name], group.attrs.get(DIGESTS, {}).get(name))
    if problem is not None:
        raise DamagedData(f"store {store}: {where}: {problem}; {repair_hint(store)}")
    return values


def repair_hint(store: str) -> str:
    """The command that restores a damaged store (the end of every :class:`DamagedData` message)."""
    return f"run `simgen repair {store}`"


def _crc(values: NDArray) -> int:
    """CRC32C of ``values`` as stored (C order, little-endian)."""
    data = np.ascontiguousarray(values, np.dtype(values.dtype).newbyteorder("<"))
    return crc32c.crc32c(data.reshape(-1).view(np.uint8))


def fingerprint_from_crcs(subject_id: str, chunk: int, start: int, stop: int, crc_u: int, crc_activation: int) -> int:
    """64-bit BLAKE2b of a chunk's place and of the CRC32C of its ``u`` and ``activation`` (never 0)."""
    h = hashlib.blake2b(json.dumps([subject_id, int(chunk), int(start), int(stop)]).encode(), digest_size=8)
    h.update(np.array([crc_u, crc_activation], "<u4").tobytes())
    return int.from_bytes(h.digest(), "little") or 1


def chunk_fingerprint(subject_id: str, chunk: int, start: int, stop: int, u: NDArray, activation: NDArray) -> int:
    """64-bit BLAKE2b of the chunk's place (subject, chunk index, sites ``[start, stop)``) and data.

    The data enter through the CRC32C of ``u`` and ``activation`` (about 1 ms
    for 29 MB), so the fingerprint costs a task or a verify next to nothing.
    Never 0, which the store's fill value keeps for "not written".
    """
    return fingerprint_from_crcs(subject_id, chunk, start, stop, _crc(u), _crc(activation))


@lru_cache(maxsize=32)
def _shift_table(n: int) -> tuple[tuple[int, ...], ...]:
    """Lookup tables of the linear map ``crc -> crc32c(n zero bytes, crc) ^ crc32c(n zero bytes)``, by byte."""
    zeros = bytes(n)
    base = crc32c.crc32c(zeros)
    columns = [crc32c.crc32c(zeros, 1 << bit) ^ base for bit in range(32)]
    tables = []
    for byte in range(4):
        table = [0] * 256
        for value in range(1, 256):
            low = value & -value  # the lowest set bit: table[value] = table[value without it] ^ its column
            table[value] = table[value ^ low] ^ columns[8 * byte + low.bit_length() - 1]
        tables.append(tuple(table))
    return tuple(tables)


def crc32c_combine(crcs: ArrayLike, length: int) -> int:
    """CRC32C of the concatenation of pieces of ``length`` bytes each, from the pieces' CRC32C.

    CRC32C is affine in its start value: ``crc(A + B) = L(crc(A)) ^ crc(B)``
    with ``L`` linear and depending on ``len(B)`` only, tabulated once per length.
    """
    t0, t1, t2, t3 = _shift_table(int(length))
    values = [int(c) for c in np.asarray(crcs).reshape(-1)]
    total = values[0]
    for c in values[1:]:
        total = t0[total & 255] ^ t1[(total >> 8) & 255] ^ t2[(total >> 16) & 255] ^ t3[total >> 24] ^ c
    return total


class _Bytes:
    """Byte ranges of one array's chunk files, from a local folder (``pread``) or any Zarr store."""

    def __init__(self, array: zarr.Array) -> None:
        self.array = array
        self.store = array.store_path.store
        self.prefix = array.store_path.path

    def key(self, coords: tuple[int, ...]) -> str:
        key = self.array.metadata.encode_chunk_key(coords)
        return f"{self.prefix}/{key}" if self.prefix else key

    def read(self, key: str, ranges: list[tuple[int, int]] | None, suffix: int | None = None) -> list[bytes] | None:
        """The byte ranges ``(start, length)`` of file ``key`` (or its last ``suffix`` bytes); ``None``: no file."""
        if isinstance(self.store, LocalStore):
            try:
                fd = os.open(Path(self.store.root) / key, os.O_RDONLY)
            except FileNotFoundError:
                return None
            try:
                if suffix is not None:
                    size = os.fstat(fd).st_size
                    return [os.pread(fd, min(suffix, size), max(size - suffix, 0))]
                return [os.pread(fd, length, start) for start, length in ranges]
            finally:
                os.close(fd)
        proto = default_buffer_prototype()
        requests = (
            [SuffixByteRequest(suffix)]
            if suffix is not None
            else [RangeByteRequest(start, start + length) for start, length in ranges]
        )
        out = []
        for request in requests:
            buf = sync(self.store.get(key, proto, byte_range=request))
            if buf is None:
                return None
            out.append(buf.to_bytes())
        return out


class SubjectReader:
    """Verified reads of one subject's ``u`` and ``activation`` (see the module docstring).

    Parameters
    ----------
    store : folder or fsspec URL of the store (as given to the other readers).
    subject_id : the subject; an unknown one is an :class:`~shared.errors.InputError`.
    version : the store's schema version (default: read from the root attributes).
    allow_pending : rows of a chunk whose ``done`` flag is 0 read as NaN instead of being refused.
    done : the done flags, if the caller has read them (``simgen status`` reads damaged ones flag by flag).
    """

    def __init__(
        self,
        store: str | Path,
        subject_id: str,
        version: int | None = None,
        allow_pending: bool = False,
        done: NDArray | None = None,
    ) -> None:
        self.store, self.subject_id, self.allow_pending = str(store), subject_id, allow_pending
        try:
            self.group = zarr.open_group(self.store, path=subject_path(subject_id), mode="r", zarr_format=3)
        except FileNotFoundError:  # zarr's GroupNotFoundError derives from it
            raise InputError(f"unknown subject {subject_id!r} in store {store}") from None
        if version is None:
            version = int(zarr.open_group(self.store, mode="r").attrs.get("schema_version", 1))
        self.version = version
        self.arrays = {name: self._member(name) for name in ("u", "activation")}
        self.n_sites = self.arrays["u"].shape[0]
        self.chunk_sites = int(self.group.attrs.get("chunk_sites") or self.arrays["u"].chunks[0])
        self.done = (self._small("done") if done is None else np.asarray(done)).astype(np.int64)
        self.fingerprints = self._small("fingerprint") if version >= SCHEMA_VERSION else None
        self._checked: set[int] = set()
        self._kept: dict[str, tuple[int, NDArray]] = {}

    # -- naming ----------------------------------------------------------------------------------------------
    def _where(self, name: str, site: int | str, file: str | None) -> str:
        at = f" (file {file})" if file else ""
        return f"store {self.store}: subject {self.subject_id}, array {name}, site {site}{at}"

    def _damaged(self, name: str, site: int | str, file: str | None, problem: str) -> DamagedData:
        return DamagedData(f"{self._where(name, site, file)}: {problem}; {repair_hint(self.store)}")

    def _file(self, name: str, chunk: int) -> str:
        arr = self.arrays[name] if name in self.arrays else self.group[name]
        key = arr.metadata.encode_chunk_key((chunk,) + (0,) * (arr.ndim - 1))
        return f"{subject_path(self.subject_id)}/{name}/{key}"

    def _member(self, name: str) -> zarr.Array:
        try:
            return self.group[name]
        except KeyError:
            where = f"{subject_path(self.subject_id)}/{name}/zarr.json"
            raise self._damaged(name, "any", where, "array missing") from None

    def _small(self, name: str) -> NDArray:
        """A small per-chunk array read whole (``done``, ``fingerprint``); a damaged one is named."""
        arr = self._member(name)
        try:
            return np.asarray(arr[...])
        except Exception as exc:  # a checksum mismatch, a truncated file
            for k in range(arr.shape[0]):  # name the flag that fails
                try:
                    arr[k]
                except Exception:
                    raise self._damaged(name, f"of chunk {k}", self._file(name, k), _why(exc)) from None
            raise self._damaged(name, "any", f"{subject_path(self.subject_id)}/{name}", _why(exc)) from None

    # -- checks ----------------------------------------------------------------------------------------------
    def _range(self, chunk: int) -> tuple[int, int]:
        start = chunk * self.chunk_sites
        return start, min(start + self.chunk_sites, self.n_sites)

    def _inner_crcs(self, name: str, chunk: int, site: int) -> list[int]:
        """The CRC32C stored with each inner chunk (site) of ``chunk``'s shard of ``name``, from its index."""
        arr = self.arrays[name]
        start, stop = self._range(chunk)
        per_shard = arr.shards[0]
        source = _Bytes(arr)
        key = source.key((chunk,) + (0,) * (arr.ndim - 1))
        file = self._file(name, chunk)
        found = source.read(key, None, suffix=index_bytes(per_shard))
        if found is None:
            raise self._damaged(name, site, file, f"shard file missing (sites {start}..{stop - 1} are done)")
        index = read_shard_index(found[0], per_shard)
        if index is None:
            raise self._damaged(name, site, file, "shard index checksum mismatch (file truncated or corrupted)")
        rows = index[: stop - start]
        missing = np.flatnonzero(rows[:, 0] == ABSENT)
        if missing.size:
            raise self._damaged(name, start + int(missing[0]), file, "site missing from its shard")
        row_bytes = int(np.prod(arr.shape[1:])) * arr.dtype.itemsize + 4
        if not (rows[:, 1] == row_bytes).all():
            raise self._damaged(name, site, file, "shard index names inner chunks of the wrong size")
        tails = source.read(key, [(int(o) + row_bytes - 4, 4) for o in rows[:, 0]])
        if tails is None or any(len(t) != 4 for t in tails):
            raise self._damaged(name, site, file, "shard file truncated")
        return [int.from_bytes(t, "little") for t in tails]

    def check_chunk(self, chunk: int, name: str = "u", site: int | None = None) -> bool:
        """Check chunk ``chunk`` (done, shard indices, fingerprint) once; ``False``: pending and ``allow_pending``."""
        if chunk in self._checked:
            return True
        start, stop = self._range(chunk)
        site = start if site is None else site
        if self.done[chunk] != 1:
            if self.done[chunk] == 0 and self.allow_pending:
                return False
            flag = int(self.done[chunk])
            state = (
                f"is not done (sites {start}..{stop - 1} never written: finish the build with `simgen build`, "
                f"which resumes, or {repair_hint(self.store)})"
                if flag == 0
                else f"has done flag {flag} (0 or 1 expected); {repair_hint(self.store)}"
            )
            raise DamagedData(f"{self._where(name, site, self._file('done', chunk))}: chunk {chunk} {state}")
        if self.fingerprints is not None:
            self._check_fingerprint(chunk, name, site)
        self._checked.add(chunk)
        return True

    def _check_fingerprint(self, chunk: int, name: str, site: int) -> None:
        start, stop = self._range(chunk)
        u, activation = self.arrays["u"], self.arrays["activation"]
        if row_shard(u) and row_shard(activation):
            crc_u = crc32c_combine(self._inner_crcs("u", chunk, site), u.dtype.itemsize * int(np.prod(u.shape[1:])))
            crc_a = crc32c_combine(
                self._inner_crcs("activation", chunk, site),
                activation.dtype.itemsize * int(np.prod(activation.shape[1:])),
            )
            found = fingerprint_from_crcs(self.subject_id, chunk, start, stop, crc_u, crc_a)
        else:  # compressed inner chunks: their checksums cover compressed bytes; decode the chunk once
            values = {key: self._chunk(key, chunk, site) for key in ("u", "activation")}
            found = chunk_fingerprint(self.subject_id, chunk, start, stop, values["u"], values["activation"])
        if int(self.fingerprints[chunk]) != found:
            raise self._damaged(
                name,
                site,
                self._file(name, chunk),
                f"chunk {chunk} (sites {start}..{stop - 1}) holds data written for another subject or other sites "
                "(content fingerprint differs: a chunk file moved or copied?)",
            )

    def _chunk(self, name: str, chunk: int, site: int) -> NDArray:
        """Every row of ``chunk`` of ``name``, decoded once (the last chunk of each array is kept)."""
        kept = self._kept.get(name)
        if kept is None or kept[0] != chunk:
            start, stop = self._range(chunk)
            kept = self._kept[name] = (chunk, self._decode(name, slice(start, stop), site, chunk))
        return kept[1]

    def _decode(self, name: str, rows: slice | int, site: int, chunk: int) -> NDArray:
        try:
            return self.arrays[name][rows]
        except Exception as exc:  # a checksum mismatch or undecodable bytes
            raise self._damaged(name, site, self._file(name, chunk), _why(exc)) from None

    # -- reads -----------------------------------------------------------------------------------------------
    def rows(self, name: str, rows: ArrayLike) -> NDArray:
        """``name[rows]`` (``u`` or ``activation``) along the site axis, every chunk it touches checked first.

        Decodes only the rows asked for in a sharded store; in an older store
        (one chunk per build task) one chunk at a time.
        """
        if name not in self.arrays:
            raise InputError(f"verified reads are of u and activation, not {name!r}")
        arr = self.arrays[name]
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if rows.size and (rows.min() < 0 or rows.max() >= self.n_sites):
            raise InputError(f"site rows {rows.tolist()} outside subject {self.subject_id}'s [0, {self.n_sites})")
        out = np.empty((rows.size, *arr.shape[1:]), dtype=arr.dtype)
        chunk_of = rows // self.chunk_sites
        step = arr.chunks[0]
        for c in np.unique(chunk_of):
            pick = np.flatnonzero(chunk_of == c)
            if not self.check_chunk(int(c), name, int(rows[pick[0]])):
                out[pick] = np.nan  # pending, and the caller asked for NaN there
                continue
            if step == 1:  # one inner chunk per site: decode only those
                for i in pick:
                    out[i] = self._decode(name, int(rows[i]), int(rows[i]), int(c))
            else:  # one chunk per build task (an older store, or a compressor's shard): decoded whole, once
                block = self._chunk(name, int(c), int(rows[pick[0]]))
                out[pick] = block[rows[pick] - self._range(int(c))[0]]
            if name == "u":
                bad = ~np.isfinite(out[pick]).reshape(len(pick), -1).all(axis=1)
                if bad.any():
                    site = int(rows[pick[np.flatnonzero(bad)[0]]])
                    raise self._damaged(name, site, self._file(name, int(c)), "non-finite values in a done chunk")
        return out

    def all(self, name: str) -> NDArray:
        """Every site row of ``name``."""
        return self.rows(name, np.arange(self.n_sites))


def _why(exc: Exception) -> str:
    """A decoding failure in words: Zarr's checksum error carries raw bytes, which name nothing."""
    text = str(exc)
    if "checksum" in text.lower():
        return "checksum mismatch (the file is corrupted)"
    first = text.splitlines()[0] if text else ""
    return f"unreadable ({type(exc).__name__}{': ' + first[:120] if first else ''})"
