"""Property-based bad input: random specs and random corruptions of a store's chunk files.

* A random build spec (valid or not) is either accepted, and then hashes, or
  refused with an :class:`~shared.errors.InputError` (a ``ConfigError``,
  ``StimulusError``, ...), never another exception.
* Random bytes flipped in a chunk file of a small store are either named by
  ``verify`` (the subject and array of that file) or leave every array's data
  as it was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.errors import InputError
from simgen.store import spec_from_mapping, spec_hash

VALID = {
    "name": "p",
    "seed": 0,
    "tissue": ["healthy"],
    "meshes": [{"id": "lv", "source": "lv", "nodes": 300}],
    "sites": {"count": 4},
    "solver": {"frames": 6},
    "output": {"chunk_sites": 2, "sock_electrodes": 20},
}

#: Keys a spec may set, by table ("" = top level, "meshes" = the first [[meshes]] table), and an unknown one each.
KEYS = {
    "": ["name", "seed", "tissue", "typo"],
    "meshes": ["id", "source", "nodes", "kind", "shape", "count", "seed", "typo"],
    "sites": ["count", "node_set", "method", "nodes", "typo"],
    "solver": [
        "frames",
        "dt",
        "diffusivity",
        "output_interval",
        "stimulus_radius",
        "stimulus_duration",
        "activation_threshold",
        "typo",
    ],
    "output": ["chunk_sites", "compressor", "level", "sock_electrodes", "typo"],
}
WORDS = ["lv", "biv", "healthy", "scar-apex", "default", "random", "farthest", "surface", "zstd", "none", "tetra", ""]
VALUES = st.one_of(
    st.integers(-3, 2_000_000),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.sampled_from(WORDS),
    st.text(max_size=6),
    st.lists(st.one_of(st.integers(-3, 400), st.sampled_from(WORDS)), max_size=4),
    st.dictionaries(st.sampled_from(["id", "x"]), st.integers(0, 3), max_size=2),
    st.none(),
)
EDITS = st.lists(
    st.sampled_from(list(KEYS)).flatmap(lambda table: st.tuples(st.just(table), st.sampled_from(KEYS[table]), VALUES)),
    min_size=1,
    max_size=4,
)


def edited(edits: list[tuple[str, str, object]]) -> dict:
    """:data:`VALID` with ``edits`` applied (table, key, value)."""
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in VALID.items()}
    data["meshes"] = [dict(VALID["meshes"][0])]
    for table, key, value in edits:
        target = data if table == "" else data["meshes"][0] if table == "meshes" else data[table]
        target[key] = value
    return data


@settings(max_examples=30, deadline=None)
@given(EDITS)
def test_a_random_spec_is_accepted_or_refused_as_bad_input(edits):
    try:
        spec = spec_from_mapping(edited(edits))
    except InputError:
        return
    assert len(spec_hash(spec)) == 64  # an accepted spec is recorded in the store


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """A small store: one 300-node LV, one setting, 4 sites in chunks of 2, 6 frames."""
    from simgen.store.runner import build

    path = tmp_path_factory.mktemp("corrupt") / "s.zarr"
    build(spec_from_mapping(VALID), path, workers=1)
    return path


def chunk_files(store: Path) -> list[Path]:
    """Every chunk file of the store's subject arrays (not the metadata)."""
    return sorted(p for p in (store / "subjects").rglob("*") if p.is_file() and "/c/" in p.as_posix())


def arrays(store: Path) -> dict[str, np.ndarray | None]:
    """Every subject array's values by path (``None``: unreadable)."""
    root = zarr.open_group(str(store), mode="r", use_consolidated=False)
    values = {}
    for path, node in root["subjects"].members(max_depth=None):
        if isinstance(node, zarr.Array):
            try:
                values[path] = node[...]
            except ValueError:  # a checksum mismatch
                values[path] = None
    return values


@pytest.fixture(scope="module")
def pristine(store) -> tuple[list[Path], dict]:
    """The store's chunk files and array values before any corruption."""
    return chunk_files(store), arrays(store)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, 10_000), where=st.floats(0, 1, exclude_max=True), mask=st.binary(min_size=1, max_size=8))
def test_a_corrupted_chunk_file_is_named_by_verify_or_harmless(store, pristine, which, where, mask):
    from simgen.store.verify import verify_store

    files, before = pristine
    path = files[which % len(files)]
    original = path.read_bytes()
    at = int(where * len(original))
    damaged = bytearray(original)
    for i, m in enumerate(mask[: len(original) - at]):
        damaged[at + i] ^= m
    path.write_bytes(bytes(damaged))
    try:
        problems = verify_store(store, sample=0).problems
        after = arrays(store)
    finally:
        path.write_bytes(original)
    subject, array = path.relative_to(store / "subjects").parts[:2]
    named = any(subject in p and array in p for p in problems)
    intact = all(np.array_equal(before[k], after[k], equal_nan=True) for k in before)
    assert named or (intact and not problems), (path, problems)
