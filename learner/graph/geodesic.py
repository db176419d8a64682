"""Geodesic (edge-path) distances on a mesh graph: the stimulus embedding's distance channel and scar maps."""

from __future__ import annotations

import weakref
from collections import OrderedDict

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra
from torch import Tensor

from learner.graph.hierarchy import Graph
from shared.graph import edge_length_graph

__all__ = ["CACHE_BYTES", "geodesic_distances"]

#: Distance rows kept per graph, in bytes; the least recently used rows go first.
CACHE_BYTES = 256 * 2**20


class _SourceRows:
    """One graph's distance rows, each computed once per source node and kept up to :data:`CACHE_BYTES`.

    A training run asks for the same few hundred stimulation sites again and
    again; a full ``N x N`` matrix would not fit for large meshes.
    """

    def __init__(self, graph: Graph) -> None:
        pos = graph.positions.detach().double().cpu().numpy()
        self.adjacency = edge_length_graph(pos, graph.edge_index.cpu().numpy().T)
        self.scale = float(np.linalg.norm(pos.max(axis=0) - pos.min(axis=0)))
        self.device = graph.edge_index.device
        self.capacity = max(1, CACHE_BYTES // (4 * graph.num_nodes))
        self.rows: OrderedDict[int, Tensor] = OrderedDict()

    def __call__(self, sources: list[int]) -> Tensor:
        missing = sorted(set(sources) - self.rows.keys())
        if missing:
            d = dijkstra(self.adjacency, directed=True, indices=missing)
            fresh = torch.as_tensor(d / self.scale, dtype=torch.float32).to(self.device)
            self.rows.update(zip(missing, fresh))
        out = torch.stack([self.rows[s] for s in sources])
        for s in sources:
            self.rows.move_to_end(s)
        while len(self.rows) > self.capacity:
            self.rows.popitem(last=False)
        return out


_CACHE: weakref.WeakKeyDictionary[Graph, _SourceRows] = weakref.WeakKeyDictionary()


def geodesic_distances(graph: Graph, sources: Tensor) -> Tensor:
    """Shortest edge-length path from each source node to every node, ``(S, N)`` float32 on the graph's device.

    Distances are divided by the diagonal of the graph's bounding box, so they
    are about 0-1 on any mesh whatever its size in millimetres. Rows are cached
    per graph object and source node (bounded by :data:`CACHE_BYTES`).
    """
    if graph not in _CACHE:
        _CACHE[graph] = _SourceRows(graph)
    return _CACHE[graph](torch.as_tensor(sources).reshape(-1).tolist())
