"""Geodesic distance rows: equal to Dijkstra on the edge-length graph, cached per graph within a byte budget."""

from __future__ import annotations

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra

import learner.graph.geodesic as geodesic
from learner.graph.hierarchy import Graph
from shared.graph import edge_length_graph


def _grid(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    ids = np.arange(n * n).reshape(n, n)
    points = np.stack([*np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), np.zeros((n, n))], -1).reshape(-1, 3)
    edges = np.concatenate(
        [np.stack([ids[:-1].ravel(), ids[1:].ravel()], 1), np.stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()], 1)]
    )
    return points.astype(float), edges


def test_rows_are_dijkstra_and_the_cache_stays_within_its_budget(monkeypatch):
    points, edges = _grid()
    graph = Graph.from_edges(points, edges)
    monkeypatch.setattr(geodesic, "CACHE_BYTES", 2 * 4 * graph.num_nodes)  # room for two rows
    sources = torch.tensor([3, 50, 3, 140])
    d = dijkstra(edge_length_graph(points, edges), directed=True, indices=sources.numpy())
    expected = torch.as_tensor(d / np.linalg.norm(points.max(0) - points.min(0)), dtype=torch.float32)
    first = geodesic.geodesic_distances(graph, sources)
    torch.testing.assert_close(first, expected)
    assert len(geodesic._CACHE[graph].rows) == 2  # the two most recent sources, 3 and 140
    torch.testing.assert_close(geodesic.geodesic_distances(graph, sources), first)
    assert set(geodesic._CACHE[graph].rows) == {3, 140}
