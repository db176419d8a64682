"""validate_mesh: one small broken mesh per failure mode, plus valid meshes and speed."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.topology import extract_surface, signed_volumes
from simgen.meshes.validate import mesh_problems, non_manifold_nodes, validate_mesh

TET_POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
#: Outward-oriented surface of TET_POINTS.
TET_SURFACE = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def two_tets() -> tuple[np.ndarray, np.ndarray]:
    """Two positively oriented tetrahedra sharing the face (1, 2, 3)."""
    points = np.vstack([TET_POINTS, [1.0, 1, 1]])
    return points, np.array([[0, 1, 2, 3], [1, 4, 2, 3]])


def oriented(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Cells reordered to positive volume."""
    cells = cells.copy()
    flip = signed_volumes(points, cells) < 0
    cells[flip] = cells[flip][:, [1, 0, 2, 3]]
    return cells


def test_two_tets_fixture_is_valid():
    points, cells = two_tets()
    mesh = Mesh(points, cells)
    assert validate_mesh(mesh) is mesh
    assert mesh_problems(mesh) == []


def test_closed_triangle_surface_is_valid():
    mesh = Mesh(TET_POINTS, TET_SURFACE)
    assert validate_mesh(mesh) is mesh


def test_open_triangle_patch_is_valid():
    mesh = Mesh(TET_POINTS, TET_SURFACE[:2])
    assert validate_mesh(mesh) is mesh


@pytest.mark.parametrize("kind", ["tetra", "triangle"])
def test_lv_ellipsoid_is_valid(kind):
    mesh = lv_ellipsoid(800, kind=kind)
    assert validate_mesh(mesh) is mesh


def test_nan_point():
    points, cells = two_tets()
    points[4, 1] = np.nan
    with pytest.raises(MeshError, match=r"1 node\(s\) with non-finite coordinates, first indices \[4\]"):
        validate_mesh(Mesh(points, cells, name="broken"))


def test_message_names_the_mesh():
    points, cells = two_tets()
    points[0, 0] = np.inf
    with pytest.raises(MeshError, match="mesh 'heart' is invalid"):
        validate_mesh(Mesh(points, cells, name="heart"))


def test_unused_node():
    points, cells = two_tets()
    points = np.vstack([points, [5.0, 5, 5]])
    with pytest.raises(MeshError, match=r"1 unused node\(s\) \(in no cell\), first indices \[5\]"):
        validate_mesh(Mesh(points, cells))


def test_unused_node_is_not_also_reported_as_disconnected():
    points, cells = two_tets()
    problems = mesh_problems(Mesh(np.vstack([points, [5.0, 5, 5]]), cells))
    assert len(problems) == 1


def test_duplicate_node():
    points, cells = two_tets()
    points = np.vstack([points, points[4] + 1e-14])
    cells = cells.copy()
    cells[1, 1] = 5  # node 4 unused, node 5 coincides with it
    with pytest.raises(MeshError, match=r"duplicate node pair\(s\) \(coincident coordinates\), first \[\[4, 5"):
        validate_mesh(Mesh(points, cells))


def test_duplicate_cell():
    points, cells = two_tets()
    cells = np.vstack([cells, cells[1, [1, 0, 2, 3]]])
    with pytest.raises(MeshError, match=r"duplicate cell\(s\) \(same node set\), first indices \[1, 2\]"):
        validate_mesh(Mesh(points, cells))


def test_degenerate_triangle():
    points = np.vstack([TET_POINTS, [0.5, 0.5, 0.0]])  # node 4 on edge (1, 2)
    cells = np.vstack([TET_SURFACE[:3], [[0, 4, 1], [0, 2, 4], [1, 4, 2]]])
    with pytest.raises(MeshError, match=r"1 degenerate cell\(s\) \(zero area\), first indices \[5\]"):
        validate_mesh(Mesh(points, cells))


def test_degenerate_tetrahedron():
    points, cells = two_tets()
    points[4] = points[[1, 2, 3]].mean(axis=0)  # on the shared face: zero volume
    with pytest.raises(MeshError, match=r"degenerate cell\(s\) \(zero volume\), first indices \[1\]"):
        validate_mesh(Mesh(points, cells))


def test_disconnected_components():
    points = np.vstack([TET_POINTS, TET_POINTS + 3.0])
    cells = np.array([[0, 1, 2, 3], [4, 5, 6, 7]])
    with pytest.raises(MeshError, match="not connected: 2 components"):
        validate_mesh(Mesh(points, cells))


def test_edge_shared_by_three_triangles():
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]])
    cells = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(
        MeshError, match=r"edge\(s\) shared by more than two triangles \(non-manifold\), first \[\[0, 1"
    ):
        validate_mesh(Mesh(points, cells))


def test_face_shared_by_three_tets():
    points = np.vstack([TET_POINTS, [1.0, 1, 1], [0.2, 0.2, -1]])
    cells = oriented(points, np.array([[0, 1, 2, 3], [1, 4, 2, 3], [1, 3, 2, 5]]))
    with pytest.raises(MeshError, match="sharing a face with two others or more"):
        validate_mesh(Mesh(points, cells))


def test_tets_sharing_only_an_edge():
    points = np.vstack([TET_POINTS, [[2.0, 0.5, 0.5], [1.5, 1.5, 0.5]]])
    cells = oriented(points, np.array([[0, 1, 2, 3], [1, 2, 4, 5]]))
    with pytest.raises(MeshError, match="boundary surface is not a closed manifold"):
        validate_mesh(Mesh(points, cells))


def test_tets_sharing_only_a_vertex():
    points = np.vstack([TET_POINTS, TET_POINTS[1:] + [1.0, 0, 0]])
    cells = oriented(points, np.array([[0, 1, 2, 3], [1, 4, 5, 6]]))  # touching at node 1
    with pytest.raises(MeshError, match=r"non-manifold boundary vertex\(s\) \(.*several fans\), first indices \[1\]"):
        validate_mesh(Mesh(points, cells))


def test_bowtie_triangles():
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    cells = np.array([[0, 1, 2], [0, 3, 4]])
    with pytest.raises(MeshError, match=r"non-manifold vertex\(s\).*first indices \[0\]"):
        validate_mesh(Mesh(points, cells))


def test_flipped_tet():
    points, cells = two_tets()
    cells[1] = cells[1, [1, 0, 2, 3]]
    with pytest.raises(MeshError, match=r"1 inverted tetrahedron\(s\) \(negative volume.*first indices \[1\]"):
        validate_mesh(Mesh(points, cells))


def test_inconsistent_triangle_winding():
    cells = TET_SURFACE.copy()
    cells[2] = cells[2, [1, 0, 2]]
    with pytest.raises(MeshError, match=r"winding inconsistent with a neighbour \(inconsistent orientation\)"):
        validate_mesh(Mesh(TET_POINTS, cells))


def test_no_cells():
    with pytest.raises(MeshError, match="no cells"):
        validate_mesh(Mesh(TET_POINTS, np.zeros((0, 4), dtype=np.int32)))


def test_several_problems_are_all_reported():
    points, cells = two_tets()
    cells = np.vstack([cells, cells[:1]])
    points = np.vstack([points, [9.0, 9, 9]])
    problems = mesh_problems(Mesh(points, cells))
    assert any("unused node" in p for p in problems)
    assert any("duplicate cell" in p for p in problems)


def test_non_manifold_nodes():
    _, cells = two_tets()
    assert len(non_manifold_nodes(cells)) == 0
    assert non_manifold_nodes(np.array([[0, 1, 2, 3], [1, 4, 5, 6]])).tolist() == [1]


def test_large_mesh_validates():
    mesh = lv_ellipsoid(50_000)
    surface = extract_surface(mesh)
    assert mesh.n_cells > 200_000
    assert mesh_problems(mesh) == [] and mesh_problems(surface) == []
