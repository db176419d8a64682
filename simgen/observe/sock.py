"""Sparse epicardial "sock" of electrodes chosen by farthest-point sampling.

Emulates the 247-electrode epicardial sock of the paper's real-data study
(about 6.5 mm electrode spacing on a human-sized ventricle). Farthest-point
sampling on the epicardial nodes spreads the electrodes near-uniformly:
each new electrode is the epicardial node with the largest Euclidean distance
to the electrodes already chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.errors import InputError
from shared.mesh import Mesh
from simgen.observe.base import ObservationOperator

__all__ = ["Sock", "farthest_point_sampling", "electrode_spacing"]


def farthest_point_sampling(points: NDArray[np.float64], n: int, start: int = 0) -> NDArray[np.int64]:
    """Indices (in selection order) of ``n`` points chosen by farthest-point sampling.

    Greedy: ``i_{k+1} = argmax_j min_{l <= k} |p_j - p_{i_l}|``, starting from
    ``start``; ties go to the lowest index, so the result is deterministic.
    Cost O(n * len(points)) time, O(len(points)) memory.
    """
    points = np.asarray(points, dtype=np.float64)
    if not 1 <= n <= len(points):
        raise InputError(f"farthest-point sampling: cannot choose {n} of {len(points)} points")
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    dist = np.linalg.norm(points - points[start], axis=1)
    for k in range(1, n):
        chosen[k] = np.argmax(dist)
        np.minimum(dist, np.linalg.norm(points - points[chosen[k]], axis=1), out=dist)
    return chosen


def electrode_spacing(mesh: Mesh, idx: NDArray[np.integer]) -> float:
    """Mean nearest-neighbour Euclidean distance (mm) between the nodes ``idx``."""
    idx = np.asarray(idx)
    if len(idx) < 2:
        raise InputError(f"electrode spacing needs at least 2 electrodes, got {len(idx)}")
    dist, _ = cKDTree(mesh.points[idx]).query(mesh.points[idx], k=2)
    return float(dist[:, 1].mean())


@dataclass(frozen=True)
class Sock(ObservationOperator):
    """``n_electrodes`` epicardial nodes spread by farthest-point sampling.

    The first electrode is the epicardial node closest to the apex
    (``mesh.axis.apex``), or, for meshes without a ventricular frame, the
    epicardial node closest to the epicardial centroid; the sampling is fully
    deterministic, so the same mesh always gives the same sock.
    """

    name: str = "electrodes"
    n_electrodes: int = 247

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.n_electrodes
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise InputError(f"sock: n_electrodes must be a positive integer, got {n!r}")

    def indices(self, mesh: Mesh) -> NDArray[np.int32]:
        epi = np.unique(mesh.nodes("epicardium"))
        if len(epi) < self.n_electrodes:
            raise InputError(
                f"sock: mesh {mesh.name!r} has {len(epi)} epicardial nodes, "
                f"fewer than n_electrodes={self.n_electrodes}; use a finer mesh or fewer electrodes "
                "(a build spec's [output] sock_electrodes, default 247; 0 stores none)"
            )
        pts = mesh.points[epi]
        anchor = mesh.axis.apex if mesh.axis is not None else pts.mean(axis=0)
        start = int(np.argmin(np.linalg.norm(pts - anchor, axis=1)))
        chosen = farthest_point_sampling(pts, int(self.n_electrodes), start)
        return np.sort(epi[chosen]).astype(np.int32)
