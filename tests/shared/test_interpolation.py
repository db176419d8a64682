"""P1 interpolation between meshes: exact for linear fields inside the mesh, weights that sum to one."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import InputError
from shared.interpolation import barycentric, interpolation_matrix
from simgen.meshes import get_mesh
from simgen.meshes.slab import slab, strip


def linear(points: np.ndarray) -> np.ndarray:
    return 2.0 * points[:, 0] - points[:, 1] + 0.5 * points[:, 2] + 3.0


def test_barycentric_coordinates_rebuild_the_point():
    rng = np.random.default_rng(0)
    corners = rng.normal(size=(5, 4, 3))
    x = rng.normal(size=(5, 3))
    lam = barycentric(corners, x)
    np.testing.assert_allclose(lam.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.einsum("sk,skd->sd", lam, corners), x, atol=1e-10)
    tri = corners[:, :3]
    lam3 = barycentric(tri, x)  # the projection onto each triangle's plane
    projected = np.einsum("sk,skd->sd", lam3, tri)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(np.einsum("sd,sd->s", x - projected, tri[:, 1] - tri[:, 0]), 0.0, atol=1e-9)
    assert np.all(np.abs(np.einsum("sd,sd->s", projected - tri[:, 0], normal)) < 1e-9)


def test_a_linear_field_is_interpolated_exactly_at_points_inside_a_volume():
    mesh = slab(10.0, 4.0, 3.0, 1.0)
    rng = np.random.default_rng(1)
    query = rng.uniform([0.1, 0.1, 0.1], [9.9, 3.9, 2.9], size=(200, 3))
    weights = interpolation_matrix(mesh.points, mesh.cells, query)
    assert weights.shape == (200, mesh.n_nodes) and (weights.data >= 0).all()
    np.testing.assert_allclose(np.asarray(weights.sum(axis=1)).ravel(), 1.0)
    np.testing.assert_allclose(weights @ linear(mesh.points), linear(query), atol=1e-9)
    at_nodes = interpolation_matrix(mesh.points, mesh.cells, mesh.points)  # a node is its own value
    np.testing.assert_allclose(at_nodes @ linear(mesh.points), linear(mesh.points), atol=1e-9)


def test_a_surface_takes_the_projection_and_points_outside_the_nearest_cell():
    surface = strip(10.0, 4.0, 0.5)
    query = np.array([[3.3, 1.7, 0.8], [12.0, 2.0, 0.0]])  # above the strip, and beyond its end
    weights = interpolation_matrix(surface.points, surface.cells, query)
    values = weights @ linear(surface.points)
    assert values[0] == pytest.approx(linear(np.array([[3.3, 1.7, 0.0]]))[0])
    assert values[1] == pytest.approx(linear(np.array([[10.0, 2.0, 0.0]]))[0])


def test_two_resolutions_of_one_heart_carry_a_field_between_them():
    coarse, fine = get_mesh("lv", 1000), get_mesh("lv", 5000)
    weights = interpolation_matrix(fine.points, fine.cells, coarse.points)
    error = np.abs(weights @ linear(fine.points) - linear(coarse.points))
    assert np.median(error) < 1e-9 and error.max() < 0.5  # surface nodes of the coarse mesh lie up to 0.2 mm off


def test_bad_input_is_refused():
    mesh = slab(2.0, 2.0, 2.0, 1.0)
    with pytest.raises(InputError, match="finite"):
        interpolation_matrix(mesh.points, mesh.cells, np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(InputError, match="cells"):
        interpolation_matrix(mesh.points, np.zeros((0, 4), int), mesh.points)
