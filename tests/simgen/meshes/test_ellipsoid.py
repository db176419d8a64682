"""Procedural LV mesh: node counts, validity, node sets and a closed boundary."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import LVGeometry, lv_ellipsoid
from simgen.meshes.topology import boundary_faces, signed_volumes
from simgen.meshes.validate import validate_mesh

SIZES = [500, 2000, 10_000]


@pytest.fixture(scope="module", params=SIZES)
def lv(request) -> Mesh:
    return lv_ellipsoid(request.param)


@pytest.mark.parametrize("kind", ["tetra", "triangle"])
@pytest.mark.parametrize("n_nodes", SIZES)
def test_node_count_on_target(n_nodes, kind):
    mesh = lv_ellipsoid(n_nodes, kind=kind)
    assert abs(mesh.n_nodes / n_nodes - 1) < 0.05
    assert mesh.cell_type == kind
    assert validate_mesh(mesh) is mesh


def test_positive_volumes(lv):
    assert (signed_volumes(lv.points, lv.cells) > 0).all()


def test_quality(lv):
    e = lv.edges()
    length = np.linalg.norm(lv.points[e[:, 0]] - lv.points[e[:, 1]], axis=1)
    assert length.min() / length.mean() > 0.15
    assert signed_volumes(lv.points, lv.cells).min() / length.mean() ** 3 > 0.01


def test_node_sets_consistent(lv):
    sets = {key: set(idx.tolist()) for key, idx in lv.node_sets.items()}
    for key in ("surface", "epicardium", "endocardium", "base"):
        assert sets[key], key
    assert sets["epicardium"] | sets["endocardium"] | sets["base"] == sets["surface"]
    assert sets["surface"] == set(np.unique(boundary_faces(lv.cells)).tolist())
    assert not sets["epicardium"] & sets["endocardium"]
    np.testing.assert_allclose(lv.points[lv.node_sets["base"], 2], LVGeometry().base_z)


def test_boundary_is_closed_manifold(lv):
    faces = boundary_faces(lv.cells)
    edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    # Outward orientation: the enclosed volume is positive and equals the tet volume.
    p = lv.points[faces]
    enclosed = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    np.testing.assert_allclose(enclosed, signed_volumes(lv.points, lv.cells).sum(), rtol=1e-9)


def test_surfaces_lie_on_the_spheroids(lv):
    geom = LVGeometry()
    surfaces = [("endocardium", geom.endo_short, geom.endo_long), ("epicardium", geom.epi_short, geom.epi_long)]
    for key, short, long in surfaces:
        p = lv.points[lv.node_sets[key]]
        level = (p[:, 0] ** 2 + p[:, 1] ** 2) / short**2 + p[:, 2] ** 2 / long**2
        np.testing.assert_allclose(level, 1.0, atol=1e-9, err_msg=key)


def test_triangle_kind_is_the_boundary():
    surface = lv_ellipsoid(2000, kind="triangle")
    np.testing.assert_array_equal(surface.node_sets["surface"], np.arange(surface.n_nodes))
    assert validate_mesh(surface) is surface


def test_axis():
    mesh = lv_ellipsoid(500)
    assert mesh.axis is not None
    np.testing.assert_allclose(mesh.axis.direction, [0, 0, 1])


@pytest.mark.parametrize("kwargs", [dict(kind="hexahedron"), dict(n_nodes=10)])
def test_bad_arguments(kwargs):
    with pytest.raises(MeshError):
        lv_ellipsoid(**kwargs)
