"""A ~500-node LV problem for the personalisation baselines: mesh, sites and solver table of the tiny store."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import zarr

from learner.observations import Observations
from shared.ecg import PseudoECG, standard_electrodes
from shared.mesh import Mesh
from shared.reader import read_mesh, read_sites
from shared.simulator import SimulatorPlugin, load_simulator
from shared.tissue import TissueFields


@dataclass
class LVProblem:
    """The tiny store's 520-node LV: 12 stimulation sites, 12 frames every 2 time units."""

    mesh: Mesh
    sites: np.ndarray
    solver: dict[str, Any]
    simulator: SimulatorPlugin

    @property
    def times(self) -> np.ndarray:
        return self.solver["output_interval"] * np.arange(1, self.solver["frames"] + 1)

    def observe(self, tissue: TissueFields, sites: np.ndarray) -> Observations:
        """Simulate ``tissue`` through the backend and observe every node."""
        u = self.simulator.simulate(self.mesh, tissue, sites, self.solver)
        return Observations(self.mesh, np.asarray(sites), u, np.ones(self.mesh.n_nodes, bool), self.times)

    def observe_ecg(self, tissue: TissueFields, sites: np.ndarray) -> Observations:
        """Simulate ``tissue`` and record the 12-lead pseudo-ECG through the standard electrodes."""
        u = self.simulator.simulate(self.mesh, tissue, sites, self.solver)
        operator = PseudoECG.assemble(self.mesh, standard_electrodes(self.mesh), tissue.D)
        ecg = np.swapaxes(u @ operator.lead_matrix().T, -1, -2)
        nobody = np.zeros(self.mesh.n_nodes, bool)
        return Observations(self.mesh, np.asarray(sites), None, nobody, self.times, ecg=ecg)


class CountingSimulator:
    """Wraps a backend and counts its calls and simulated sequences."""

    def __init__(self, backend: SimulatorPlugin) -> None:
        self.backend, self.calls, self.sequences = backend, 0, 0

    def simulate(self, mesh, tissue, sites, solver):
        self.calls += 1
        self.sequences += len(sites)
        return self.backend.simulate(mesh, tissue, sites, solver)


@pytest.fixture(scope="session")
def lv(tiny_store) -> LVProblem:
    """The tiny store's ``lv`` mesh with its sites and the store's solver table."""
    solver = dict(zarr.open_group(str(tiny_store), mode="r").attrs["spec"]["solver"])
    return LVProblem(read_mesh(tiny_store, "lv"), read_sites(tiny_store, "lv"), solver, load_simulator())


@pytest.fixture
def counting(lv) -> CountingSimulator:
    """A fresh call counter around the real backend."""
    return CountingSimulator(lv.simulator)
