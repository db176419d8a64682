"""The shared Mesh type: shape checks, node sets, edges."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh

POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])


def test_tetra_basics():
    m = Mesh(POINTS, np.array([[0, 1, 2, 3]]), {"surface": [0, 1, 2, 3]})
    assert (m.n_nodes, m.n_cells, m.cell_type) == (4, 1, "tetra")
    assert m.edges().shape == (6, 2)
    assert m.cells.dtype == np.int32 and m.nodes("surface").dtype == np.int32
    assert m.mean_edge_length() == pytest.approx((3 + 3 * np.sqrt(2)) / 6)


@pytest.mark.parametrize(
    "points, cells, sets, match",
    [
        (POINTS[:, :2], [[0, 1, 2]], {}, r"points must have shape \(N, 3\)"),
        (POINTS, [[0, 1]], {}, "cells must have shape"),
        (POINTS, [[0, 1, 7]], {}, "out of range"),
        (POINTS, [[0, 1, 2]], {"surface": [9]}, "node set 'surface'"),
    ],
)
def test_shape_errors(points, cells, sets, match):
    with pytest.raises(MeshError, match=match):
        Mesh(points, np.array(cells), sets)


def test_missing_node_set_is_named():
    with pytest.raises(MeshError, match="no node set 'epicardium'"):
        Mesh(POINTS, np.array([[0, 1, 2]])).nodes("epicardium")


def test_long_axis():
    axis = LongAxis(apex=np.zeros(3), base=np.array([0, 0, 2.0]), reference=np.array([1.0, 0, 0]))
    assert axis.length == 2.0
    np.testing.assert_allclose(axis.direction, [0, 0, 1])
