"""A surface that passes through itself is found (and refused as a heart); touching is not crossing."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes import save_mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.folds import crossing_triangles

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)


def _two_triangles(second: np.ndarray) -> int:
    points = np.vstack([SQUARE[:3], second])
    return len(crossing_triangles(points, np.array([[0, 1, 2], [3, 4, 5]])))


def test_crossing_against_a_direct_construction():
    assert _two_triangles(np.array([[0.6, 0.2, -1], [0.6, 0.2, 1], [0.6, -2, 0]])) == 1  # an edge pierces it
    assert _two_triangles(np.array([[0.6, 0.2, 0.5], [0.6, 0.2, 1], [0.6, -2, 0.7]])) == 0  # above it
    assert _two_triangles(np.array([[0.5, 0.2, 0.0], [0.6, 0.2, 1], [0.6, -2, 1]])) == 0  # touches it
    assert _two_triangles(np.array([[3, 3, -1], [3, 3, 1], [3, 4, 0]])) == 0  # far away
    # sharing a node, as parts welded at a seam do: crossing where the opposite edge pierces, not at the node
    shared = np.vstack([SQUARE[:3], [[0.6, 0.2, -1], [0.6, 0.2, 1]]])
    assert len(crossing_triangles(shared, np.array([[0, 1, 2], [1, 3, 4]]))) == 1
    fan = np.vstack([SQUARE[:3], [[0.0, 1.0, 1.0], [1.0, 1.0, 1.0]]])  # a fold up from the shared node
    assert len(crossing_triangles(fan, np.array([[0, 1, 2], [2, 3, 4]]))) == 0


@pytest.mark.parametrize("source", ["lv", "biv"])
@pytest.mark.parametrize("kind", ["tetra", "triangle"])
def test_sound_hearts_do_not_cross(source, kind):
    mesh = get_mesh(source, 1000, kind)
    tris = mesh.cells if kind == "triangle" else None
    if tris is None:
        from simgen.meshes.topology import boundary_faces

        tris = boundary_faces(mesh.cells)
    assert len(crossing_triangles(mesh.points, tris)) == 0


def test_a_folded_lv_is_refused_as_a_heart(tmp_path):
    lv = get_mesh("lv", 1000, "triangle")
    points = lv.points.copy()
    far = points[:, 0] > 0.5 * points[:, 0].max()
    points[far, 0] *= -0.9  # that part of the wall pushed through the opposite one
    path = save_mesh(Mesh(points, lv.cells, name="folded"), tmp_path / "folded.vtu")
    with pytest.raises(MeshError, match=r"folded\.vtu: its surface passes through itself \(\d+ pair"):
        get_mesh(str(path))
    assert get_mesh(str(path), heart=False).n_nodes == lv.n_nodes  # no heart: accepted as it is
