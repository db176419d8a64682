"""Observation of a whole named node set: every surface node, or the epicardium only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from shared.mesh import Mesh
from simgen.observe.base import ObservationOperator

__all__ = ["NodeSetObservation", "AllSurface", "Epicardial"]


@dataclass(frozen=True)
class NodeSetObservation(ObservationOperator):
    """Observe every node of the mesh's node set ``node_set``."""

    node_set: str = "surface"

    def indices(self, mesh: Mesh) -> NDArray[np.int32]:
        return np.unique(mesh.nodes(self.node_set)).astype(np.int32)


@dataclass(frozen=True)
class AllSurface(NodeSetObservation):
    """All surface nodes: endocardium, epicardium and base rim (all nodes of a triangle mesh)."""

    name: str = "surface"
    node_set: str = "surface"


@dataclass(frozen=True)
class Epicardial(NodeSetObservation):
    """Epicardial nodes only (e.g. optical mapping, an epicardial sock with full coverage)."""

    name: str = "epicardium"
    node_set: str = "epicardium"
