"""Procedural BiV mesh: node counts, validity, quality, node sets and geometry."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.biventricular import BiVGeometry, biv_ellipsoid
from simgen.meshes.ellipsoid import LVGeometry
from simgen.meshes.topology import boundary_faces, signed_volumes
from simgen.meshes.validate import validate_mesh

GEOM = BiVGeometry()
LV = GEOM.lv
SIZES = [500, 2000, 20_000]


@pytest.fixture(scope="module", params=SIZES)
def biv(request) -> Mesh:
    return biv_ellipsoid(request.param)


@pytest.fixture(scope="module")
def biv_surface() -> Mesh:
    return biv_ellipsoid(2000, kind="triangle")


def edge_lengths(mesh: Mesh) -> np.ndarray:
    e = mesh.edges()
    return np.linalg.norm(mesh.points[e[:, 0]] - mesh.points[e[:, 1]], axis=1)


def spheroid_level(points: np.ndarray, centre, axes) -> np.ndarray:
    return (((points - np.asarray(centre)) / np.asarray(axes)) ** 2).sum(axis=1)


@pytest.mark.parametrize("kind", ["tetra", "triangle"])
@pytest.mark.parametrize("n_nodes", [500, 1234, 5000])
def test_node_count_on_target(n_nodes, kind):
    mesh = biv_ellipsoid(n_nodes, kind=kind)
    assert abs(mesh.n_nodes / n_nodes - 1) < 0.05
    assert mesh.cell_type == kind


def test_fixture_sizes_on_target(biv, request):
    target = request.node.callspec.params["biv"]
    assert abs(biv.n_nodes / target - 1) < 0.05


def test_valid_with_positive_volumes(biv):
    assert validate_mesh(biv) is biv
    assert (signed_volumes(biv.points, biv.cells) > 0).all()


def test_quality_fit_for_explicit_fem(biv):
    length = edge_lengths(biv)
    assert length.min() / length.mean() > 0.15
    assert signed_volumes(biv.points, biv.cells).min() / length.mean() ** 3 > 0.01


def test_node_sets(biv):
    sets = {key: set(idx.tolist()) for key, idx in biv.node_sets.items()}
    for key in ("surface", "epicardium", "endocardium", "lv_endocardium", "rv_endocardium", "base"):
        assert sets[key], key
    assert sets["surface"] == set(np.unique(boundary_faces(biv.cells)).tolist())
    assert sets["endocardium"] == sets["lv_endocardium"] | sets["rv_endocardium"]
    assert not sets["lv_endocardium"] & sets["rv_endocardium"]
    assert not sets["epicardium"] & sets["endocardium"]
    assert sets["epicardium"] | sets["endocardium"] | sets["base"] == sets["surface"]
    np.testing.assert_allclose(biv.points[biv.node_sets["base"], 2], GEOM.base_z)


def test_surfaces_lie_on_the_spheroids(biv):
    p = biv.points
    below = p[:, 2] < GEOM.base_z - 1e-6
    lv_endo = biv.node_sets["lv_endocardium"]
    lv_endo = lv_endo[below[lv_endo]]
    level = spheroid_level(p[lv_endo], (0, 0, 0), (LV.endo_short, LV.endo_short, LV.endo_long))
    np.testing.assert_allclose(level, 1.0, atol=1e-9)
    # RV endocardium: the RV endocardial ellipsoid or the septal LV epicardium.
    rv = biv.node_sets["rv_endocardium"]
    on_rv = np.abs(spheroid_level(p[rv], GEOM.rv_centre, GEOM.rv_endo_axes) - 1) < 1e-9
    lv_epi_axes = (LV.epi_short, LV.epi_short, LV.epi_long)
    on_lv = np.abs(spheroid_level(p[rv], (0, 0, 0), lv_epi_axes) - 1) < 1e-9
    assert (on_rv | on_lv).all() and on_rv.any() and on_lv.any()


def test_rv_is_on_the_plus_x_side(biv):
    p = biv.points
    rv = p[biv.node_sets["rv_endocardium"]]
    lv = p[biv.node_sets["lv_endocardium"]]
    assert rv[:, 0].mean() > lv[:, 0].mean() + 10.0
    assert (rv[:, 0] > -LV.epi_short * 0.5).all()
    reference_side = (rv - biv.axis.base) @ biv.axis.reference
    assert np.median(reference_side) > 0
    # The far free wall reaches well beyond the LV epicardium (it wraps the LV on +x).
    assert p[:, 0].max() > LV.epi_short + 15.0
    assert p[:, 0].min() > -LV.epi_short - 1e-6


def test_axis():
    mesh = biv_ellipsoid(500)
    np.testing.assert_allclose(mesh.axis.apex, [0, 0, -LV.epi_long])
    np.testing.assert_allclose(mesh.axis.base, [0, 0, GEOM.base_z])
    np.testing.assert_allclose(mesh.axis.reference, [1, 0, 0])
    assert -LV.epi_long - 1e-9 < mesh.points[:, 2].min() < -LV.epi_long + 1.0
    assert mesh.name == "biv"


def test_triangle_surface(biv_surface):
    assert validate_mesh(biv_surface) is biv_surface
    np.testing.assert_array_equal(biv_surface.node_sets["surface"], np.arange(biv_surface.n_nodes))
    e = np.sort(biv_surface.cells[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert (counts == 2).all()  # closed
    for key in ("epicardium", "lv_endocardium", "rv_endocardium", "base"):
        assert len(biv_surface.node_sets[key]) > 0


def test_surface_encloses_a_positive_volume(biv_surface):
    p = biv_surface.points[biv_surface.cells]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    assert volume > 0  # outward orientation
    lv_wall = 4 / 3 * np.pi * (35**2 * 65 - 25**2 * 57) / 2
    assert lv_wall < volume < 4 * lv_wall


def test_deterministic():
    a, b = biv_ellipsoid(600), biv_ellipsoid(600)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.cells, b.cells)


def test_custom_geometry():
    geom = BiVGeometry(rv_centre=(14.0, 0, 0), rv_endo_axes=(36.0, 44, 50), rv_epi_axes=(42.0, 50, 56))
    mesh = biv_ellipsoid(1500, geometry=geom, name="wide")
    assert mesh.name == "wide" and abs(mesh.n_nodes / 1500 - 1) < 0.05
    assert (signed_volumes(mesh.points, mesh.cells) > 0).all()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(rv_endo_axes=(45.0, 38.0, 50.0)), "RV endocardial semi-axes"),
        (dict(lv=LVGeometry(base_z=52.0)), "base plane must cut the RV"),
        (dict(rv_centre=(0.0, 0.0, 0.0), rv_endo_axes=(30.0, 38.0, 50.0)), "reach beyond the LV epicardium"),
    ],
)
def test_geometry_checks(kwargs, match):
    with pytest.raises(MeshError, match=match):
        BiVGeometry(**kwargs)


def test_unsupported_geometry_is_refused():
    far = BiVGeometry(rv_centre=(60.0, 0, 0), rv_endo_axes=(20.0, 20, 30), rv_epi_axes=(25.0, 25, 35))
    with pytest.raises(MeshError, match="enter the RV cavity away from the LV epicardium"):
        biv_ellipsoid(1000, geometry=far)


@pytest.mark.parametrize(
    "kwargs, match", [(dict(kind="hexahedron"), "unknown mesh kind"), (dict(n_nodes=10), "n_nodes")]
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(MeshError, match=match):
        biv_ellipsoid(**kwargs)
