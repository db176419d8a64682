"""Version-1 stores (built before the metadata of version 2): read with a note, never written, rebuilt with --force."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

from shared.errors import SchemaError
from shared.reader import check_store, read_mesh, read_split, read_statistics, read_tissue, subject_ids
from shared.schema import SCHEMA_VERSION, SchemaWarning
from simgen.store.card import dataset_card
from simgen.store.edit import add_subject, regenerate
from simgen.store.layout import StoreMismatch
from simgen.store.runner import build
from simgen.store.spec import MeshEntry
from simgen.store.verify import verify_store

#: The solver table of a version-1 store: edge-path stimulus patches (the reference spec's frames).
OLD_SOLVER = {"frames": 8, "stimulus_radius": 12.0, "stimulus_region": "geodesic"}


@pytest.fixture
def old_store(tiny_spec, tmp_path, as_version_1) -> Path:
    """The reference spec built with the edge-path stimulus that stores of version 1 ran, downgraded to version 1."""
    store = tmp_path / "old.zarr"
    build(tiny_spec(solver=OLD_SOLVER), store, workers=1)
    as_version_1(store)
    return store


def test_version_1_store_is_read_with_a_note(old_store, reference_store):
    with pytest.warns(SchemaWarning, match="schema_version 1.*simgen build SPEC --store .* --force"):
        check_store(old_store)
    assert subject_ids(old_store) == subject_ids(reference_store)
    assert np.array_equal(read_mesh(old_store, "lv").points, read_mesh(reference_store, "lv").points)
    assert np.array_equal(read_tissue(old_store, "lv-healthy").a, read_tissue(reference_store, "lv-healthy").a)
    assert read_statistics(old_store) is None and read_statistics(old_store, "lv-healthy") is None
    assert read_split(old_store) == {}
    with pytest.warns(SchemaWarning):
        report = verify_store(old_store, sample=1)
    assert report.ok, report.problems
    with pytest.warns(SchemaWarning):
        card = dataset_card(old_store)
    assert "not recorded (schema version 1)" in card and "| lv | 520 |" in card


def test_version_1_store_is_not_written(old_store, tmp_path, tiny_spec):
    entry = MeshEntry(id="more", source="lv", nodes=500)
    for edit in (
        lambda: add_subject(old_store, entry, ["healthy"], workers=1),
        lambda: regenerate(old_store, ["lv-healthy"], workers=1),
    ):
        with pytest.raises(
            SchemaError,
            match=f"schema_version 1, this simgen writes version {SCHEMA_VERSION} only"
            r".*simgen build SPEC --store .* --force",
        ):
            edit()
    with pytest.raises(StoreMismatch, match=f"schema version 1, this simgen writes version {SCHEMA_VERSION}.*--force"):
        build(tiny_spec(solver=OLD_SOLVER), old_store, workers=1)
    rebuilt = build(tiny_spec(solver=OLD_SOLVER), old_store, workers=1, force=True)  # at the current version
    assert rebuilt.tasks_run == 4
    assert check_store(old_store)["schema_version"] == SCHEMA_VERSION and verify_store(old_store, sample=0).ok


def test_unknown_version_is_refused_with_the_rebuild_command(old_store):
    zarr.open_group(str(old_store), mode="r+").attrs["schema_version"] = 99
    with pytest.raises(
        SchemaError,
        match=r"schema_version 99, this code reads versions 1, 2, 3; rebuild it with "
        r"`simgen build SPEC --store .*old.zarr --force`",
    ):
        check_store(old_store)
