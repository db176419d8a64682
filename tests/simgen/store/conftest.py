"""Shared helpers of the build tests: a tiny spec and byte-level store comparison.

Separate builds compared byte for byte must share their creation date (root
attribute ``provenance``): ``SOURCE_DATE_EPOCH`` fixes it for every build of
these tests, client processes and workers included.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from simgen.store import BuildSpec, spec_from_mapping


def tiny_spec(**patch) -> BuildSpec:
    """One 500-node LV, two tissue settings, 6 sites in chunks of 3, short output: 4 tasks."""
    data = {
        "meshes": [{"id": "lv", "source": "lv", "nodes": 500}],
        "tissue": ["healthy", "scar-apex"],
        "sites": {"count": 6},
        "solver": {"frames": 8},
        "output": {"chunk_sites": 3, "sock_electrodes": 40},
    }
    return spec_from_mapping({**data, **patch})


def store_bytes(store: Path) -> dict[str, bytes]:
    """Every file of a store (relative path -> bytes), the lock file excepted."""
    return {
        str(p.relative_to(store)): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file() and p.name != ".lock"
    }


#: The creation date of every store these tests build (2024-01-01T00:00:00Z).
BUILD_EPOCH = "1704067200"


@pytest.fixture(scope="session", autouse=True)
def fixed_build_date():
    """``SOURCE_DATE_EPOCH`` set for the session (inherited by the processes the tests start), then restored."""
    saved = os.environ.get("SOURCE_DATE_EPOCH")
    os.environ["SOURCE_DATE_EPOCH"] = BUILD_EPOCH
    yield
    if saved is None:
        os.environ.pop("SOURCE_DATE_EPOCH", None)
    else:
        os.environ["SOURCE_DATE_EPOCH"] = saved


@pytest.fixture(scope="session")
def reference_store(tmp_path_factory) -> Path:
    """An uninterrupted build of :func:`tiny_spec`, shared by the comparisons."""
    from simgen.store.runner import build

    store = tmp_path_factory.mktemp("ref") / "ref.zarr"
    build(tiny_spec(), store, workers=2)
    return store


@pytest.fixture
def reference_commit(reference_store, monkeypatch) -> None:
    """New provenance records the git commit the reference store records, so that a store laid out anew
    compares byte for byte with it even when the checkout's HEAD moved since the reference was built."""
    import json

    recorded = json.loads((reference_store / "zarr.json").read_text())["attributes"]["provenance"]["git_commit"]
    monkeypatch.setattr("simgen.store.metadata._git_commit", lambda: recorded)


@pytest.fixture(name="tiny_spec", scope="session")
def tiny_spec_fixture():
    """The :func:`tiny_spec` factory."""
    return tiny_spec


@pytest.fixture(name="store_bytes")
def store_bytes_fixture():
    """The :func:`store_bytes` snapshot function."""
    return store_bytes
