"""A tiny dataset store shared by the learner tests (built once per session by simgen)."""

from __future__ import annotations

from pathlib import Path

import pytest

from simgen.build import spec_from_mapping
from simgen.build.runner import build

TINY_STORE_SPEC = {
    "meshes": [
        {"id": "lv", "source": "lv", "nodes": 500},
        {"id": "lv-b", "source": "lv", "nodes": 600},
    ],
    "tissue": ["healthy", "scar-apex", "scar-anterior-mid"],
    "sites": {"count": 12},
    "solver": {"frames": 12, "output_interval": 2.0},
    "output": {"chunk_sites": 4, "sock_electrodes": 40},
}


@pytest.fixture(scope="session")
def tiny_store(tmp_path_factory) -> Path:
    """2 LV meshes x 3 tissue settings = 6 subjects, 12 sites each, 12 frames every 2 time units."""
    store = tmp_path_factory.mktemp("learner") / "tiny.zarr"
    build(spec_from_mapping(TINY_STORE_SPEC), store, workers=1)
    return store


def tiny_config(store: Path, out: Path, kind: str = "metapns", **train):
    """A small model and short training on :func:`tiny_store` (seconds per epoch)."""
    from learner.config import config_from_mapping

    return config_from_mapping(
        {
            "out": str(out),
            "data": {
                "store": str(store),
                "workers": 0,
                "split": {"seed": 0, "validation": 0.2, "test": 0.2},
                "episodes": {"context": [1, 3], "targets": 4, "observe": "surface"},
            },
            "model": {
                "kind": kind,
                "channels": [4, 8],
                "hidden": 16,
                "latent": 8,
                "levels": 3,
                "coarsest": 10,
                "coarse_blocks": 1,
            },
            "train": {"epochs": 2, "validate_every": 1, **train},
        }
    )


@pytest.fixture(name="tiny_config")
def tiny_config_fixture():
    """The :func:`tiny_config` factory."""
    return tiny_config
