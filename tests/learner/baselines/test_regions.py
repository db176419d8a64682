"""Mesh regions: the requested number of connected, similar-sized regions, deterministically."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from learner.baselines.regions import mesh_regions, region_sizes
from shared.errors import InputError


def test_seven_connected_regions_of_similar_size(lv):
    labels = mesh_regions(lv.mesh)
    assert labels.shape == (lv.mesh.n_nodes,) and labels.dtype == np.int64
    sizes = region_sizes(labels)
    assert len(sizes) == 7 and sizes.sum() == lv.mesh.n_nodes
    assert sizes.max() < 3 * sizes.min()
    edges = lv.mesh.edges()
    for r in range(7):
        inside = edges[(labels[edges[:, 0]] == r) & (labels[edges[:, 1]] == r)]
        nodes = np.flatnonzero(labels == r)
        local = np.searchsorted(nodes, inside)
        graph = coo_matrix((np.ones(len(local)), (local[:, 0], local[:, 1])), shape=(len(nodes),) * 2)
        assert connected_components(graph, directed=False)[0] == 1, f"region {r} is not connected"
    np.testing.assert_array_equal(mesh_regions(lv.mesh), labels)


def test_one_region_and_bad_counts(lv):
    assert not mesh_regions(lv.mesh, 1).any()
    for bad in (0, lv.mesh.n_nodes + 1, 2.5, True):
        with pytest.raises(InputError, match="region count"):
            mesh_regions(lv.mesh, bad)
