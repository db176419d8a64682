"""Geodesic (edge-path) distances on a mesh graph: the stimulus embedding's distance channel and scar maps."""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import ArrayLike
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from torch import Tensor

from learner.graph.hierarchy import Graph, _adjacency, _undirected

__all__ = ["edge_length_graph", "geodesic_distances"]


def edge_length_graph(points: ArrayLike, edges: ArrayLike) -> csr_matrix:
    """Symmetric sparse matrix of Euclidean edge lengths for ``edges`` (E, 2) in either direction."""
    points = np.asarray(points, dtype=np.float64)
    return _adjacency(points, _undirected(np.asarray(edges), len(points)))


def geodesic_distances(graph: Graph, sources: Tensor) -> Tensor:
    """Shortest edge-length path from each source node to every node, ``(S, N)`` float32.

    Distances are divided by the diagonal of the graph's bounding box, so they
    are about 0-1 on any mesh whatever its size in millimetres.
    """
    pos = graph.positions.detach().double().cpu().numpy()
    adjacency = edge_length_graph(pos, graph.edge_index.cpu().numpy().T)
    d = dijkstra(adjacency, directed=True, indices=np.asarray(torch.as_tensor(sources).cpu(), np.int64).reshape(-1))
    scale = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))
    return torch.as_tensor(d / scale, dtype=torch.float32, device=graph.edge_index.device)
