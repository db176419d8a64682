"""Sharded result arrays: one shard per build task, one inner chunk per site, so that a simulation reads alone;
a damaged inner chunk is named by verify; version-2 (unsharded) stores still read."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.storage import LocalStore

from shared.errors import SchemaError
from shared.reader import check_store, read_u
from shared.schema import SchemaWarning
from simgen.store.edit import regenerate
from simgen.store.verify import verify_store


@pytest.fixture
def store(reference_store, tmp_path) -> Path:
    """A private copy of the reference store (6 sites in shards of 3) that a test may damage."""
    copy = tmp_path / "s.zarr"
    shutil.copytree(reference_store, copy)
    return copy


class CountingStore(LocalStore):
    """A read-only local store that adds up the bytes it hands to Zarr."""

    def __init__(self, root: Path) -> None:
        super().__init__(root, read_only=True)
        self.bytes_read = 0

    async def get(self, key, prototype, byte_range=None):
        value = await super().get(key, prototype, byte_range)
        self.bytes_read += 0 if value is None else len(value)
        return value


def _inner_chunk_bytes(u: zarr.Array) -> int:
    """Bytes of one site's inner chunk of ``u``: the values and their CRC32C."""
    return int(np.prod(u.chunks)) * u.dtype.itemsize + 4


def _damage(store: Path, subject_id: str, site: int) -> None:
    """Flip one byte of ``site``'s inner chunk in its shard of ``u``."""
    u = zarr.open_array(str(store / "subjects" / subject_id / "u"), mode="r")
    shard, inner = divmod(site, u.shards[0])
    path = store / "subjects" / subject_id / "u" / "c" / str(shard) / "0" / "0"
    data = bytearray(path.read_bytes())
    data[inner * _inner_chunk_bytes(u) + 10] ^= 0xFF
    path.write_bytes(bytes(data))


def test_a_shard_holds_one_task_and_an_inner_chunk_one_site(reference_store):
    u = zarr.open_array(str(reference_store / "subjects/lv-healthy/u"), mode="r")
    assert (u.shards, u.chunks) == ((3, *u.shape[1:]), (1, *u.shape[1:]))
    shards = sorted(p.name for p in (reference_store / "subjects/lv-healthy/u/c").iterdir())
    assert shards == ["0", "1"]  # one file per build task
    index_bytes = 3 * 16 + 4  # offset and length per inner chunk, then the index's CRC32C
    shard = reference_store / "subjects/lv-healthy/u/c/0/0/0"
    assert shard.stat().st_size == 3 * _inner_chunk_bytes(u) + index_bytes


def test_reading_one_simulation_decodes_only_its_inner_chunk(store, reference_store):
    expected = zarr.open_array(str(reference_store / "subjects/lv-healthy/u"), mode="r")[4]
    _damage(store, "lv-healthy", 3)
    _damage(store, "lv-healthy", 5)  # both other sites of the shard
    counting = CountingStore(store)
    u = zarr.open_array(counting, path="subjects/lv-healthy/u", mode="r")
    before = counting.bytes_read
    assert np.array_equal(u[4], expected)
    assert counting.bytes_read - before == _inner_chunk_bytes(u) + 3 * 16 + 4  # its inner chunk and the index
    assert np.array_equal(read_u(store, "lv-healthy", [4])[0], expected)  # the reader the learner uses
    with pytest.raises(ValueError, match="checksum"):
        u[3]


def test_verify_names_the_subject_and_site_of_a_damaged_inner_chunk(store):
    _damage(store, "lv-scar-apex", 4)
    report = verify_store(store, sample=0)
    assert len(report.problems) == 1, report.problems
    problem = report.problems[0]
    assert "subject lv-scar-apex chunk 1 (sites 3..5)" in problem and "u chunk unreadable" in problem
    assert "file subjects/lv-scar-apex/u/c/1/0/0, sites [4]" in problem


def test_regenerate_rewrites_a_damaged_shard(store, reference_store, store_bytes):
    _damage(store, "lv-healthy", 1)
    regenerate(store, ["lv-healthy"], sites=[1], workers=1)
    assert verify_store(store, sample=0).ok
    assert (store / "subjects/lv-healthy/u/c/0/0/0").read_bytes() == (
        reference_store / "subjects/lv-healthy/u/c/0/0/0"
    ).read_bytes()


def test_version_2_store_reads_with_a_note_and_is_not_written(store, reference_store, as_version_2):
    as_version_2(store)
    u = zarr.open_array(str(store / "subjects/lv-healthy/u"), mode="r")
    assert u.shards is None and u.chunks == (3, *u.shape[1:])  # one chunk per build task
    with pytest.warns(SchemaWarning, match="schema_version 2: read without what version 3 added: sharding"):
        check_store(store)
    reference = zarr.open_array(str(reference_store / "subjects/lv-healthy/u"), mode="r")
    assert np.array_equal(u[4], reference[4])
    with pytest.warns(SchemaWarning):
        report = verify_store(store, sample=1)
    assert report.ok, report.problems
    with pytest.raises(SchemaError, match="schema_version 2, this simgen writes version 3 only"):
        regenerate(store, ["lv-healthy"], workers=1)
