"""Split a mesh into a few contiguous regions: the segments whose excitability FS-BO fits.

The paper fits excitability on a seven-segment division of the heart. Here the
segments come from the mesh graph alone (no anatomical frame needed): graph
Voronoi cells around farthest-point seeds, relaxed by a few Lloyd steps, as
the coarsening of :mod:`learner.graph.hierarchy` does. Every region is
connected, and the split is a deterministic function of the mesh.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from learner.graph.hierarchy import _cluster
from shared.errors import InputError, MeshError
from shared.graph import edge_length_graph, undirected_edges
from shared.mesh import Mesh

__all__ = ["mesh_regions", "region_sizes"]

#: Segments of the paper's division of the ventricles.
DEFAULT_REGIONS = 7


def mesh_regions(mesh: Mesh, count: int = DEFAULT_REGIONS) -> NDArray[np.int64]:
    """Region (0 .. count - 1) of every node: ``count`` connected regions of similar size.

    Parameters
    ----------
    mesh : a connected mesh.
    count : number of regions, 1 <= count <= number of nodes.
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= mesh.n_nodes:
        raise InputError(f"region count must be an integer in [1, {mesh.n_nodes}], got {count!r}")
    und = undirected_edges(mesh.edges(), mesh.n_nodes)
    n_comp, _ = connected_components(edge_length_graph(mesh.points, und), directed=False)
    if n_comp != 1:
        raise MeshError(f"mesh {mesh.name!r} has {n_comp} connected components; regions need a connected mesh")
    if count == 1:
        return np.zeros(mesh.n_nodes, dtype=np.int64)
    labels = _cluster(mesh.points, und, int(count))
    found = int(labels.max()) + 1
    if found != count:
        raise InputError(f"mesh {mesh.name!r} splits into only {found} regions, fewer than the {count} asked for")
    return labels


def region_sizes(labels: NDArray[np.integer]) -> NDArray[np.int64]:
    """Number of nodes in each region."""
    return np.bincount(np.asarray(labels, dtype=np.int64))
