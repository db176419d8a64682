"""The simulator plug-in contract: simgen's backend is found by name and reproduces the store."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from shared.errors import InputError
from shared.reader import read_mesh, read_sites, read_tissue
from shared.simulator import SimulatorPlugin, available_simulators, load_simulator


def test_simgen_registers_the_aliev_panfilov_backend():
    assert "aliev-panfilov" in available_simulators()
    assert isinstance(load_simulator("aliev-panfilov"), SimulatorPlugin)


def test_unknown_backend_is_refused_with_the_installed_names():
    with pytest.raises(InputError, match="no simulator plug-in 'nope'.*aliev-panfilov"):
        load_simulator("nope")


def test_backend_reproduces_the_stored_simulations(tmp_path):
    from simgen.store import spec_from_mapping
    from simgen.store.runner import build

    spec = {
        "meshes": [{"id": "lv", "source": "lv", "nodes": 500}],
        "tissue": ["scar-apex"],
        "sites": {"count": 4},
        "solver": {"frames": 6},
        "output": {"chunk_sites": 4, "sock_electrodes": 0},
    }
    store = tmp_path / "s.zarr"
    build(spec_from_mapping(spec), store, workers=1)
    solver = dict(zarr.open_group(str(store), mode="r").attrs["spec"])["solver"]
    sites = read_sites(store, "lv")[[1, 3]]
    u = load_simulator().simulate(read_mesh(store, "lv"), read_tissue(store, "lv-scar-apex"), sites, solver)
    stored = zarr.open_group(str(store), path="subjects/lv-scar-apex", mode="r")["u"][[1, 3]]
    np.testing.assert_array_equal(u, stored)
