"""Edge-length graphs and store locations, used by simgen and learner alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.errors import InputError
from shared.graph import edge_length_graph, undirected_edges
from shared.location import is_url, resolve_location


def test_edge_length_graph_is_symmetric_with_one_entry_per_edge():
    points = np.array([[0.0, 0, 0], [3, 0, 0], [3, 4, 0], [3, 4, 0]])
    edges = np.array([[0, 1], [1, 0], [1, 2], [2, 2], [2, 3]])  # a repeat, a self loop, coincident points
    graph = edge_length_graph(points, edges).toarray()
    np.testing.assert_array_equal(graph, graph.T)
    assert graph[0, 1] == 3.0 and graph[1, 2] == 4.0 and graph[0, 2] == 0.0
    assert 0 < graph[2, 3] <= 1e-11  # kept as an edge: csgraph reads a stored zero as none
    np.testing.assert_array_equal(undirected_edges(edges, 4), [[0, 1], [1, 2], [2, 3]])


@pytest.mark.parametrize(
    "edges, match",
    [(np.zeros((2, 3), int), r"shape \(E, 2\)"), (np.zeros((1, 2)), "integer"), (np.array([[0, 4]]), "outside")],
)
def test_bad_edges_are_refused(edges, match):
    with pytest.raises(InputError, match=match):
        undirected_edges(edges, 4)


def test_locations():
    assert is_url("s3://bucket/x.zarr") and is_url("simplecache::s3://b/x.zarr")
    assert not is_url("data/x.zarr") and not is_url(Path("s3:/x"))
    assert resolve_location("x.zarr", "/data") == str(Path("/data/x.zarr").resolve())
    assert resolve_location("s3://b/x.zarr", "/data") == "s3://b/x.zarr"
    assert resolve_location("", "/data") == ""
