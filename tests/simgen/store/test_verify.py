"""``verify_store``: a clean store passes; damaged, unfinished or altered chunks are named."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr

from shared.errors import SchemaError
from shared.schema import SCHEMA_VERSION
from shared.split import canonical_part
from simgen.store.fingerprint import chunk_fingerprint
from simgen.store.stats import chunk_moments, statistics
from simgen.store.verify import verify_store


@pytest.fixture
def store(reference_store, tmp_path) -> Path:
    """A private copy of the reference store that a test may damage."""
    copy = tmp_path / "s.zarr"
    shutil.copytree(reference_store, copy)
    return copy


def _subject(store: Path, subject_id: str) -> zarr.Group:
    return zarr.open_group(str(store), path=f"subjects/{subject_id}", mode="r+")


def _only_problem(store: Path, **kw) -> str:
    report = verify_store(store, **kw)
    assert not report.ok and len(report.problems) == 1, report.problems
    return report.problems[0]


def test_clean_store_verifies(reference_store):
    report = verify_store(reference_store)
    assert report.ok, report.problems
    assert (report.chunks_checked, report.chunks_recomputed) == (4, 2)
    assert verify_store(reference_store, sample=10).chunks_recomputed == 4


def test_garbage_chunk_file_is_named(store):
    (store / "subjects/lv-healthy/u/c/1/0/0").write_bytes(b"\x00garbage" * 64)
    problem = _only_problem(store, sample=10)
    assert "lv-healthy chunk 1" in problem and "unreadable" in problem
    assert "subjects/lv-healthy/u/c/1/0/0" in problem


@pytest.mark.parametrize("array, key", [("u", "c/0/0/0"), ("activation", "c/1/0")])
def test_truncated_chunk_file_is_named(store, array, key):
    path = store / "subjects/lv-scar-apex" / array / key
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    problem = _only_problem(store, sample=10)
    chunk = key.split("/")[1]
    assert f"lv-scar-apex chunk {chunk}" in problem and f"{array} chunk unreadable" in problem


def test_missing_chunk_file_reads_as_unwritten(store):
    (store / "subjects/lv-healthy/u/c/0/0/0").unlink()  # reads back as the NaN fill value
    problem = _only_problem(store)
    assert "lv-healthy chunk 0" in problem and "non-finite" in problem


def test_cleared_done_flag_is_reported(store):
    _subject(store, "lv-scar-apex")["done"][1] = 0
    report = verify_store(store)
    assert report.problems == ["subject lv-scar-apex chunk 1 (sites 3..5) not done"]
    assert report.chunks_checked == 3


def test_out_of_range_values_are_reported(store):
    _subject(store, "lv-healthy")["u"][3:6] = 2.0
    problem = _only_problem(store, sample=0)
    assert "lv-healthy chunk 1" in problem and "outside [-0.5, 1.5]" in problem


def test_altered_valid_data_is_caught_by_its_moments(store):
    g = _subject(store, "lv-healthy")
    g["u"][0:3] = g["u"][0:3] * 0.5  # finite, in range, but no longer what the chunk's moments describe
    problem = _only_problem(store, sample=0)
    assert problem == "subject lv-healthy chunk 0 (sites 0..2): stored moments differ from the chunk's data"


def test_altered_valid_data_is_caught_by_recomputation(store):
    g = _subject(store, "lv-healthy")
    # finite, in range, with matching moments and fingerprint: only recomputation can tell
    g["u"][0:3] = u = g["u"][0:3] * 0.5
    g["moments"][0] = chunk_moments(u, g["activation"][0:3])
    g["fingerprint"][0] = chunk_fingerprint("lv-healthy", 0, 0, 3, u, g["activation"][0:3])
    stats = dict(g.attrs["statistics"])
    g.attrs["statistics"] = statistics(g["moments"][...])
    root = zarr.open_group(str(store), mode="r+")
    root.attrs["statistics"] = statistics(
        np.concatenate([_subject(store, s)["moments"][...] for s in ("lv-healthy", "lv-scar-apex")])
    )
    assert g.attrs["statistics"] != stats
    assert verify_store(store, sample=0).ok
    problem = _only_problem(store, sample=10)
    assert "lv-healthy chunk 0" in problem and "differs from recomputation" in problem


def test_statistics_that_disagree_with_the_moments_are_reported(store):
    g = _subject(store, "lv-scar-apex")
    g.attrs["statistics"] = {**g.attrs["statistics"], "u": {**g.attrs["statistics"]["u"], "mean": 0.5}}
    assert _only_problem(store, sample=0) == "subject lv-scar-apex: statistics attribute differs from its chunk moments"


@pytest.mark.parametrize("name, attrs", [("u", {"units": "mV"}), ("x", {"long_name": None})])
def test_wrong_cf_attributes_are_reported(store, name, attrs):
    arr = _subject(store, "lv-healthy")[name]
    arr.attrs.update(attrs)
    problem = _only_problem(store, sample=0)
    assert problem.startswith(f"subject lv-healthy: {name} has attributes") and "schema expects" in problem


def test_coordinates_and_split_are_checked_against_the_mesh(store):
    g = _subject(store, "lv-healthy")
    g["site"][0] = g["site"][0] + 1
    g.attrs["split"] = next(p for p in ("train", "test") if p != g.attrs["split"])
    assert verify_store(store, sample=0).problems == [
        "subject lv-healthy: site differs from its recorded digest (file subjects/lv-healthy/site/c/0)",
        f"subject lv-healthy: split attribute {g.attrs['split']!r}, the canonical split assigns "
        f"{canonical_part('lv-healthy')!r}",
    ]


def test_wrong_schema_version_is_refused(store):
    zarr.open_group(str(store), mode="r+").attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(SchemaError, match="schema_version"):
        verify_store(store)
