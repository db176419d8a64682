"""Geodesic scar library: data materials, geodesic discs, library-like sizes, reproducible."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from learner.baselines.tissue_library import A_BORDER, A_CORE, geodesic_diameter, geodesic_scar, scar_library
from shared.errors import InputError
from shared.graph import edge_length_graph


def test_a_scar_is_a_geodesic_disc_with_a_border_band(lv):
    mesh = lv.mesh
    adj = edge_length_graph(mesh.points, mesh.edges())
    dist = dijkstra(adj, indices=100)
    a = geodesic_scar(mesh, 100, radius=20.0, border_width=8.0)
    np.testing.assert_array_equal(a == A_CORE, dist <= 20.0)
    np.testing.assert_array_equal(a == A_BORDER, (dist > 20.0) & (dist <= 28.0))
    np.testing.assert_array_equal(a == 0.15, dist > 28.0)
    assert (geodesic_scar(mesh, 100, 0.0) == A_CORE).sum() == 1
    with pytest.raises(InputError, match="not a node"):
        geodesic_scar(mesh, mesh.n_nodes, 10.0)


def test_library_is_healthy_first_then_scars_of_plausible_size(lv):
    maps = scar_library(lv.mesh, count=60, seed=1)
    assert maps.shape == (60, lv.mesh.n_nodes) and maps.dtype == np.float32
    assert np.all(maps[0] == np.float32(0.15))
    assert set(np.unique(maps).tolist()) <= {np.float32(0.15), np.float32(A_BORDER), np.float32(A_CORE)}
    core = (maps[1:] == np.float32(A_CORE)).mean(axis=1)
    assert core.min() > 0 and 0.01 < np.median(core) < 0.2  # an AHA segment is ~6% of the LV
    np.testing.assert_array_equal(scar_library(lv.mesh, count=60, seed=1), maps)
    assert not np.array_equal(scar_library(lv.mesh, count=60, seed=2), maps)
    assert 60.0 < geodesic_diameter(lv.mesh) < 200.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"count": 1}, "count >= 2"), ({"radius": (0.3, 0.1)}, "radius"), ({"border_width": -1.0}, "border_width")],
)
def test_library_refuses_bad_settings(lv, kwargs, message):
    with pytest.raises(InputError, match=message):
        scar_library(lv.mesh, **kwargs)
