"""Observation of the epicardial nodes only (e.g. optical mapping, ECGI targets)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from shared.mesh import Mesh
from simgen.observe.base import ObservationOperator

__all__ = ["Epicardial"]


@dataclass(frozen=True)
class Epicardial(ObservationOperator):
    """Observe the mesh's ``epicardium`` node set."""

    name: str = "epicardium"

    def indices(self, mesh: Mesh) -> NDArray[np.int32]:
        return np.unique(mesh.nodes("epicardium")).astype(np.int32)
