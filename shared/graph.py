"""Mesh graphs weighted by edge length: the geodesic distances of stimulus patches, scars and surrogates."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import csr_matrix

from shared.errors import InputError

__all__ = ["undirected_edges", "edge_length_graph"]


def undirected_edges(edges: ArrayLike, n_nodes: int) -> NDArray[np.int64]:
    """Unique undirected edges ``(E, 2)``, lower id first, sorted, self loops dropped.

    Raises
    ------
    InputError
        ``edges`` is not an integer ``(E, 2)`` array of node ids in ``[0, n_nodes)``.
    """
    edges = np.asarray(edges)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise InputError(f"edges must have shape (E, 2), got {edges.shape}")
    if edges.size and not np.issubdtype(edges.dtype, np.integer):
        raise InputError(f"edges must be integer node ids, got dtype {edges.dtype}")
    e = edges.astype(np.int64)
    if e.size and (e.min() < 0 or e.max() >= n_nodes):
        raise InputError(f"edges reference node ids outside [0, {n_nodes})")
    e = np.sort(e, axis=1)
    e = e[e[:, 0] != e[:, 1]]
    return np.unique(e, axis=0) if len(e) else e.reshape(0, 2)


def edge_length_graph(points: ArrayLike, edges: ArrayLike) -> csr_matrix:
    """Symmetric sparse ``(N, N)`` matrix of the Euclidean lengths of ``edges`` (either direction, repeats allowed).

    Pass it to :func:`scipy.sparse.csgraph.dijkstra` for geodesic (edge-path)
    distances. A zero length (coincident points) is raised to ``1e-12`` of the
    longest edge, since csgraph reads a stored zero as a missing edge.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    und = undirected_edges(edges, n)
    length = np.linalg.norm(points[und[:, 0]] - points[und[:, 1]], axis=1)
    length = np.maximum(length, 1e-12 * max(float(length.max(initial=0.0)), 1.0))
    rows = np.concatenate([und[:, 0], und[:, 1]])
    cols = np.concatenate([und[:, 1], und[:, 0]])
    return csr_matrix((np.concatenate([length, length]), (rows, cols)), shape=(n, n))
