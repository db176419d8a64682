"""Fixtures shared by the simgen and learner tests: stores of an older schema version."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import zarr

from shared.reader import subject_ids
from shared.schema import SUBJECT_ARRAYS

#: Root and subject attributes added by schema version 2.
NEW_ROOT_ATTRS = ("provenance", "simulation", "split", "statistics", "summary")
NEW_SUBJECT_ATTRS = ("solver", "split", "statistics")


def as_version_1(store: Path) -> None:
    """Strip what version 2 added (arrays, attributes, CF attributes) and mark the store version 1."""
    from simgen.build.store import consolidate_metadata

    root = zarr.open_group(str(store), mode="r+", use_consolidated=False)
    for subject_id in subject_ids(store):
        g = root[f"subjects/{subject_id}"]
        for name, spec in SUBJECT_ARRAYS.items():
            if spec.since == 2:
                shutil.rmtree(store / "subjects" / subject_id / name)
        g.attrs.put({k: v for k, v in g.attrs.items() if k not in NEW_SUBJECT_ATTRS})
    for _, node in root.members(max_depth=None):  # the arrays' CF attributes
        if isinstance(node, zarr.Array):
            node.attrs.put({})
    root.attrs.put({**{k: v for k, v in root.attrs.items() if k not in NEW_ROOT_ATTRS}, "schema_version": 1})
    consolidate_metadata(store)


@pytest.fixture(name="as_version_1")
def as_version_1_fixture():
    """The :func:`as_version_1` downgrade of a local store built by this version."""
    return as_version_1
