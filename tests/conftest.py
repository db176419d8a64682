"""Fixtures shared by the shared, simgen and learner tests: a tiny store, stores of an older schema version."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import zarr

from shared.reader import subject_ids
from shared.schema import SHARDED_ARRAYS, SUBJECT_ARRAYS

#: Root and subject attributes added by schema version 2.
NEW_ROOT_ATTRS = ("provenance", "simulation", "split", "statistics", "summary")
NEW_SUBJECT_ATTRS = ("solver", "split", "statistics")


def as_version_2(store: Path) -> None:
    """Strip the arrays version 3 added, rewrite ``u`` and ``activation`` unsharded (one chunk per build
    task, as version 2 stored them) and mark the store version 2."""
    from simgen.store.layout import consolidate_metadata

    root = zarr.open_group(str(store), mode="r+", use_consolidated=False)
    for subject_id in subject_ids(store):
        g = root[f"subjects/{subject_id}"]
        for name, spec in SUBJECT_ARRAYS.items():
            if spec.since == 3:
                shutil.rmtree(store / "subjects" / subject_id / name, ignore_errors=True)
        for name in SHARDED_ARRAYS:
            old = g[name]
            values, attrs = old[...], old.attrs.asdict()
            shutil.rmtree(store / "subjects" / subject_id / name)
            g.create_array(
                name,
                shape=old.shape,
                chunks=old.shards,
                dtype=old.dtype,
                fill_value=old.fill_value,
                compressors=old.compressors,
                dimension_names=old.metadata.dimension_names,
                attributes=attrs,
            )[...] = values
    root.attrs["schema_version"] = 2
    consolidate_metadata(store)


@pytest.fixture(name="as_version_2")
def as_version_2_fixture():
    """The :func:`as_version_2` downgrade of a local store built by this version."""
    return as_version_2


def as_version_1(store: Path) -> None:
    """Strip what version 2 added (arrays, attributes, CF attributes) from the :func:`as_version_2` store and
    mark it version 1."""
    from simgen.store.layout import consolidate_metadata

    as_version_2(store)
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


TINY_STORE_SPEC = {
    "meshes": [
        {"id": "lv", "source": "lv", "nodes": 500},
        {"id": "lv-b", "source": "lv", "nodes": 600},
    ],
    "tissue": ["healthy", "scar-apex", "scar-anterior-mid"],
    "sites": {"count": 12},
    # a patch of about 1.5 edges of these ~9 mm-edge meshes: the 10 mm default holds a site and its nearest ring
    "solver": {"frames": 12, "output_interval": 2.0, "stimulus_radius": 14.0},
    "output": {"chunk_sites": 4, "sock_electrodes": 40},
}


@pytest.fixture(scope="session")
def tiny_store(tmp_path_factory) -> Path:
    """2 LV meshes x 3 tissue settings = 6 subjects, 12 sites each, 12 frames every 2 time units."""
    from simgen.store import spec_from_mapping
    from simgen.store.runner import build

    store = tmp_path_factory.mktemp("tiny") / "tiny.zarr"
    build(spec_from_mapping(TINY_STORE_SPEC), store, workers=1)
    return store


#: The tiny build spec of tests/simgen/store/conftest.py (``tiny_spec``) as a spec file's text:
#: 2 subjects x 2 chunks of 3 sites on a 500-node LV; a build of it resumes that reference store.
TINY_SPEC_TOML = """
tissue = ["healthy", "scar-apex"]
[[meshes]]
id = "lv"
source = "lv"
nodes = 500
[sites]
count = 6
[solver]
frames = 8
[output]
chunk_sites = 3
sock_electrodes = 40
"""


@pytest.fixture(name="tiny_spec_toml", scope="session")
def tiny_spec_toml_fixture() -> str:
    """:data:`TINY_SPEC_TOML`."""
    return TINY_SPEC_TOML
