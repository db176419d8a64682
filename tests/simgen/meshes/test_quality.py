"""Element quality against hand-computed values: regular, right-angled and sliver tetrahedra, triangles."""

from __future__ import annotations

import numpy as np
import pytest

from shared.mesh import Mesh
from simgen.meshes import lv_ellipsoid
from simgen.meshes.quality import altitudes, cell_angles, mesh_quality, radius_ratios

REGULAR = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
CORNER = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TET = np.array([[0, 1, 2, 3]])


def sliver(h: float) -> np.ndarray:
    """Edges (+-1, 0, 0) and (0, +-1, h): two crossing segments a height ``h`` apart."""
    return np.array([[1, 0, 0], [-1, 0, 0], [0, 1, h], [0, -1, h]], dtype=float)


def test_regular_tetrahedron():
    q = mesh_quality(Mesh(REGULAR, TET))
    assert q.min_angle == pytest.approx(np.degrees(np.arccos(1 / 3)))  # 70.53
    assert q.min_angle == pytest.approx(70.528779, abs=1e-6)
    assert q.min_radius_ratio == pytest.approx(1.0) and q.mean_radius_ratio == pytest.approx(1.0)
    assert q.min_altitude_ratio == pytest.approx(np.sqrt(2 / 3))  # altitude sqrt(2/3) a, every edge a
    assert q.nodes == 4 and q.cells == 1 and q.cell_type == "tetra"
    assert q.mean_edge == pytest.approx(2 * np.sqrt(2))


def test_right_angled_corner_tetrahedron():
    angles = cell_angles(CORNER, TET)[0]
    # edges from the right-angled corner: 90 degrees; edges of the oblique face: arccos(1/sqrt(3)) = 54.74
    np.testing.assert_allclose(angles[:3], 90.0)
    np.testing.assert_allclose(angles[3:], np.degrees(np.arccos(1 / np.sqrt(3))))
    # volume 1/6, faces 1/2 (x3) and sqrt(3)/2: r = 3V / S = 1 / (3 + sqrt(3)); R = sqrt(3) / 2
    r, R = 1 / (3 + np.sqrt(3)), np.sqrt(3) / 2
    assert radius_ratios(CORNER, TET)[0] == pytest.approx(3 * r / R)  # 0.732
    assert altitudes(CORNER, TET)[0] == pytest.approx(1 / np.sqrt(3))  # corner to the oblique face
    q = mesh_quality(Mesh(CORNER, TET))
    assert q.min_altitude_ratio == pytest.approx((1 / np.sqrt(3)) / ((3 + 3 * np.sqrt(2)) / 6))  # 0.478


@pytest.mark.parametrize("h", [0.1, 0.01])
def test_sliver(h):
    p = sliver(h)
    angles = cell_angles(p, TET)[0]
    # at the edges (0,1) and (2,3) the two faces open by the angle between (0, +-1, h): 180 - 2 atan(h)
    np.testing.assert_allclose(angles[[0, 5]], 180 - 2 * np.degrees(np.arctan(h)))
    # at the other four: the angle between the other two corners seen along the edge, measured directly
    for k, (i, j) in enumerate([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]):
        axis = (p[j] - p[i]) / np.linalg.norm(p[j] - p[i])
        u, w = (p[m] - p[i] - ((p[m] - p[i]) @ axis) * axis for m in sorted({0, 1, 2, 3} - {i, j}))
        expected = np.degrees(np.arccos(u @ w / np.linalg.norm(u) / np.linalg.norm(w)))
        assert angles[k] == pytest.approx(expected)
    assert angles.min() < 2 * np.degrees(h)
    # V = 2h/3, four faces of area sqrt(1 + h^2): r = h / (2 sqrt(1 + h^2)); R = sqrt(1 + h^2/4)
    expected = 3 * h / (2 * np.sqrt(1 + h**2) * np.sqrt(1 + h**2 / 4))
    assert radius_ratios(p, TET)[0] == pytest.approx(expected)  # 0.149 for h = 0.1
    assert altitudes(p, TET)[0] == pytest.approx(2 * h / np.sqrt(1 + h**2))


def test_triangles():
    p = np.array([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0], [0, 1, 0], [10, 0.5, 0]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 1, 3], [0, 4, 3]])
    np.testing.assert_allclose(cell_angles(p, tris)[0], 60.0)
    np.testing.assert_allclose(np.sort(cell_angles(p, tris)[1]), [45.0, 45.0, 90.0])
    ratio = radius_ratios(p, tris)
    assert ratio[0] == pytest.approx(1.0) and ratio[1] == pytest.approx(2 * (1 - 1 / np.sqrt(2)) / (np.sqrt(2) / 2))
    np.testing.assert_allclose(altitudes(p, tris)[:2], [np.sqrt(3) / 2, np.sqrt(2) / 2])
    assert altitudes(p, tris)[2] == pytest.approx(2 * 5.0 / np.hypot(10, 0.5))  # twice the area / longest side
    q = mesh_quality(Mesh(p[:3], tris[:1]))
    assert q.min_angle == pytest.approx(60.0) and q.min_altitude_ratio == pytest.approx(np.sqrt(3) / 2)


def test_summary_and_rows_of_a_procedural_mesh():
    q = mesh_quality(lv_ellipsoid(400, "tetra"))
    summary = q.summary()
    assert summary["cell_type"] == "tetra" and summary["nodes"] == q.nodes
    assert 0 < q.min_angle < 70.6 and 0 < q.min_radius_ratio <= q.p01_radius_ratio <= q.mean_radius_ratio <= 1
    labels = [label for label, _ in q.rows()]
    assert labels == [
        "smallest dihedral angle (deg)",
        "radius ratio min / 1st pct / mean",
        "smallest altitude / mean edge",
    ]
