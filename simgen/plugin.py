"""simgen's simulator plug-in for ``shared.simulator`` (entry point ``metapns.simulators: aliev-panfilov``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from shared.config import from_mapping
from shared.mesh import Mesh
from shared.tissue import TissueFields
from simgen.solver.simulate import Simulator, SolverConfig

__all__ = ["AlievPanfilovPlugin"]


class AlievPanfilovPlugin:
    """The batched Aliev-Panfilov solver behind the :class:`shared.simulator.SimulatorPlugin` protocol."""

    def __init__(self, threads: int = 1) -> None:
        self.threads = threads

    def simulate(
        self, mesh: Mesh, tissue: TissueFields, sites: NDArray[np.integer], solver: Mapping[str, Any]
    ) -> NDArray[np.float32]:
        config = from_mapping(SolverConfig, dict(solver), "solver")
        return Simulator(mesh, tissue, config).run(np.asarray(sites, np.int64), threads=self.threads).u
