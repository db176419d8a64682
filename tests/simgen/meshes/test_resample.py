"""Resampling to a node target: isotropic remeshing (no needles), node counts, TetGen fills of known quality."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import trimesh

from shared.mesh import Mesh
from simgen.meshes import get_mesh, lv_ellipsoid
from simgen.meshes.io import load_mesh, save_mesh
from simgen.meshes.quality import mesh_quality
from simgen.meshes.remesh import closest_points, crossing_edges, remesh
from simgen.meshes.resample import hausdorff_distance, resample
from simgen.meshes.shipped import unpacked
from simgen.meshes.topology import extract_surface
from simgen.meshes.validate import mesh_problems

from .conftest import dense_biv

#: Node counts must be within this fraction of the target.
TOLERANCE = 0.15
#: Smallest triangle angle after remeshing (degrees): 25.2 to 38.9 measured over the surfaces below.
MIN_TRIANGLE_ANGLE = 24.0
#: TetGen fills of remeshed surfaces: smallest dihedral angle 4.5 to 5.3 degrees, smallest altitude
#: 0.047 to 0.067 mean edges (before remeshing: 0.1 to 1.4 degrees, 0.0007 to 0.02 mean edges).
MIN_DIHEDRAL, MIN_ALTITUDE = 3.0, 0.03
REAL = ["real:rodero01-lv", "real:tof-biv", "real:cobiveco-mean-biv"]


def check(mesh: Mesh, nodes: int, kind: str) -> None:
    """Node count within :data:`TOLERANCE`, cell type, a surface that does not cross itself, and the quality
    bounds of the kind."""
    assert mesh.cell_type == kind and abs(mesh.n_nodes / nodes - 1) <= TOLERANCE, mesh.n_nodes
    surface = extract_surface(mesh)
    assert crossing_edges(surface.points, surface.cells) == 0
    q = mesh_quality(mesh)
    if kind == "triangle":
        assert q.min_angle >= MIN_TRIANGLE_ANGLE, q
    else:
        assert q.min_angle >= MIN_DIHEDRAL and q.min_altitude_ratio >= MIN_ALTITUDE, q


@pytest.mark.parametrize(
    ("source", "nodes", "kind"),
    [(source, 1000, kind) for source in REAL for kind in ("triangle", "tetra")]
    + [("real:rodero01-lv", 5000, "triangle"), ("real:tof-biv", 5000, "tetra")],  # refined; 10-15 s each at 5,000
)
def test_shipped_meshes_reach_the_target(source, nodes, kind):
    check(get_mesh(source, nodes, kind), nodes, kind)


@pytest.fixture(scope="module")
def dense() -> Mesh:
    return dense_biv()


@pytest.mark.parametrize("kind", ["triangle", "tetra"])
def test_dense_biv_surface(dense, kind):
    assert dense.n_nodes > 28_000
    mesh = resample(dense, 1000, kind)
    check(mesh, 1000, kind)
    assert hausdorff_distance(dense, mesh) < extract_surface(mesh).mean_edge_length()  # 4.0-4.4 mm, edges 6-8 mm


@pytest.mark.parametrize("kind", ["triangle", "tetra"])
def test_surface_merged_from_three_parts(merged_file, kind, caplog):
    with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
        raw = load_mesh(merged_file)
    assert "winding" in caplog.text and mesh_quality(raw).min_angle < 1.0  # mis-wound part, seam slivers
    check(get_mesh(str(merged_file), 1000, kind), 1000, kind)  # loaded again, then resampled


@pytest.mark.parametrize("kind", ["triangle", "tetra"])
def test_merged_and_dense_surfaces_at_5000_nodes(merged_file, dense, kind):
    """Finer meshes of the hard surfaces: crease junctions that fold a remeshed fan, creases that leave a
    needle after the last smoothing (6 to 25 s each)."""
    source = load_mesh(merged_file) if kind == "tetra" else dense
    check(resample(source, 5000, kind), 5000, kind)


def test_ct_volume_mesh():
    with unpacked("real:rodero01-lv") as path:
        raw = load_mesh(path, units="mm")
    assert raw.cell_type == "tetra" and 4500 < raw.n_nodes < 6000 and mesh_quality(raw).min_angle < 10
    for nodes in (1000, 2000):
        check(resample(raw, nodes, "tetra"), nodes, "tetra")


def test_remeshing_an_open_surface_keeps_its_boundary():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=30.0)
    keep = sphere.triangles_center[:, 2] < 10.0
    cap = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    cap.remove_unreferenced_vertices()
    points, tris = remesh(cap.vertices, cap.faces, 6.0)
    mesh = Mesh(points, tris)
    assert not mesh_problems(mesh) and mesh_quality(mesh).min_angle >= MIN_TRIANGLE_ANGLE
    assert closest_points(points, cap.vertices, cap.faces)[1].max() < 1e-6  # on the original surface
    rim, old_rim = boundary(points, tris), boundary(cap.vertices, cap.faces)
    a, b = cap.vertices[old_rim[:, 0]], cap.vertices[old_rim[:, 1]]
    for p in points[np.unique(rim)]:  # every remeshed rim node lies on the original rim
        t = np.clip(np.einsum("ij,ij->i", p - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
        assert np.linalg.norm(a + t[:, None] * (b - a) - p, axis=1).min() < 1e-9


def boundary(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Edges in one triangle only."""
    edges = np.sort(np.asarray(tris)[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    return unique[count == 1]


def test_resampling_is_deterministic_and_keeps_good_meshes(tmp_path):
    first, second = (get_mesh("real:tof-biv", 700, "triangle") for _ in range(2))
    np.testing.assert_array_equal(first.points, second.points)
    np.testing.assert_array_equal(first.cells, second.cells)
    procedural = lv_ellipsoid(1000, "tetra")
    assert resample(procedural, 1050, "tetra") is procedural  # within tolerance, no angle below 10 degrees
    save_mesh(first, tmp_path / "tof.vtu")
    assert get_mesh(str(tmp_path / "tof.vtu"), first.n_nodes, "triangle").n_nodes == first.n_nodes
