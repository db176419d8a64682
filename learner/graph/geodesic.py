"""Geodesic (edge-path) distances on a mesh graph: the stimulus embedding's distance channel."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.csgraph import dijkstra
from torch import Tensor

from learner.graph.hierarchy import Graph

__all__ = ["geodesic_distances"]


def geodesic_distances(graph: Graph, sources: Tensor) -> Tensor:
    """Shortest edge-length path from each source node to every node, ``(S, N)`` float32.

    Distances are divided by the diagonal of the graph's bounding box, so they
    are about 0-1 on any mesh whatever its size in millimetres.
    """
    pos = graph.positions.detach().double().numpy()
    src, dst = graph.edge_index.numpy()
    lengths = np.linalg.norm(pos[src] - pos[dst], axis=1)
    adjacency = sp.csr_matrix((lengths, (src, dst)), shape=(graph.num_nodes, graph.num_nodes))
    d = dijkstra(adjacency, directed=False, indices=np.asarray(sources, np.int64).reshape(-1))
    scale = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))
    return torch.as_tensor(d / scale, dtype=torch.float32)
