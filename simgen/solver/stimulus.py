"""Stimulus patches: the nodes excited at t = 0 around each stimulation site."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra

from shared.errors import StimulusError
from shared.mesh import Mesh
from simgen.meshes.topology import edge_graph

__all__ = ["check_sites", "patch_mask"]


def check_sites(mesh: Mesh, sites: NDArray[np.integer]) -> NDArray[np.int64]:
    """Validate stimulation node ids (integers in ``[0, N)``) and return them as int64."""
    arr = np.asarray(sites)
    if arr.ndim != 1 or arr.size == 0:
        raise StimulusError(f"stimulation sites must be a non-empty 1-D list of node ids, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise StimulusError(f"stimulation sites must be integer node ids, got dtype {arr.dtype}")
    bad = arr[(arr < 0) | (arr >= mesh.n_nodes)]
    if bad.size:
        raise StimulusError(
            f"unknown stimulation node(s) {bad[:5].tolist()}: mesh {mesh.name!r} has nodes 0..{mesh.n_nodes - 1}"
        )
    return arr.astype(np.int64)


def patch_mask(
    mesh: Mesh, sites: NDArray[np.integer], radius: float, graph: sp.csr_matrix | None = None
) -> NDArray[np.bool_]:
    """Boolean (N, S) mask of nodes within geodesic (edge-path) distance ``radius`` mm of each site.

    The site itself is always included, so ``radius = 0`` excites one node.
    ``graph``: ``edge_graph(mesh)`` if the caller keeps it (built otherwise).
    """
    sites = check_sites(mesh, sites)
    if not np.isfinite(radius) or radius < 0:
        raise StimulusError(f"stimulus radius must be >= 0 mm, got {radius}")
    unique, inverse = np.unique(sites, return_inverse=True)
    graph = edge_graph(mesh) if graph is None else graph
    dist = dijkstra(graph, directed=False, indices=unique, limit=radius * (1 + 1e-9))
    return (dist <= radius * (1 + 1e-9)).T[:, inverse]
