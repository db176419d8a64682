"""Observation of every surface node (endocardium, epicardium and base rim)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from shared.mesh import Mesh
from simgen.observe.base import ObservationOperator

__all__ = ["AllSurface"]


@dataclass(frozen=True)
class AllSurface(ObservationOperator):
    """Observe the mesh's ``surface`` node set (all nodes of a triangle mesh)."""

    name: str = "surface"

    def indices(self, mesh: Mesh) -> NDArray[np.int32]:
        return np.unique(mesh.nodes("surface")).astype(np.int32)
