"""load_mesh / save_mesh: round trips per format, and clear errors for bad files."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh
from simgen.meshes.biventricular import biv_ellipsoid
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.io import AXIS_ARRAYS, load_mesh, save_mesh
from simgen.meshes.topology import boundary_faces

TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])


@pytest.fixture(scope="module", params=["tetra", "triangle"])
def mesh(request) -> Mesh:
    return lv_ellipsoid(600, kind=request.param)


def assert_same(loaded: Mesh, mesh: Mesh) -> None:
    np.testing.assert_allclose(loaded.points, mesh.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loaded.cells, mesh.cells)
    assert sorted(loaded.node_sets) == sorted(mesh.node_sets)
    for key, idx in mesh.node_sets.items():
        np.testing.assert_array_equal(loaded.node_sets[key], np.sort(idx), err_msg=key)


@pytest.mark.parametrize("suffix", [".vtu", ".vtk", ".msh"])
def test_round_trip(mesh, suffix, tmp_path):
    path = save_mesh(mesh, tmp_path / f"heart{suffix}")
    assert path.is_file()
    assert_same(load_mesh(path), mesh)


def test_round_trip_keeps_non_standard_node_sets(tmp_path):
    mesh = biv_ellipsoid(600)
    loaded = load_mesh(save_mesh(mesh, tmp_path / "biv.vtu"))
    assert_same(loaded, mesh)
    assert "rv_endocardium" in loaded.node_sets


def test_triangle_round_trip_through_ply(tmp_path):
    mesh = lv_ellipsoid(600, kind="triangle")
    assert_same(load_mesh(save_mesh(mesh, tmp_path / "lv.ply")), mesh)


def test_stl_keeps_geometry(tmp_path):
    mesh = lv_ellipsoid(600, kind="triangle")
    loaded = load_mesh(save_mesh(mesh, tmp_path / "lv.stl"))
    assert loaded.n_nodes == mesh.n_nodes and loaded.n_cells == mesh.n_cells
    assert list(loaded.node_sets) == ["surface"]


def test_name_and_axis(tmp_path):
    """The long axis travels as three constant point-data vectors; ``axis=`` replaces it."""
    mesh = lv_ellipsoid(600)
    path = save_mesh(mesh, tmp_path / "subject07.vtu")
    assert load_mesh(path).name == "subject07"
    read = load_mesh(path).axis
    for name in ("apex", "base", "reference"):
        np.testing.assert_allclose(getattr(read, name), getattr(mesh.axis, name))
    axis = LongAxis(apex=np.zeros(3), base=np.array([0.0, 0, 1]), reference=np.array([1.0, 0, 0]))
    loaded = load_mesh(path, name="lv", axis=axis)
    assert loaded.name == "lv" and loaded.axis is axis
    plain = tmp_path / "plain.vtu"
    meshio.write(plain, meshio.Mesh(mesh.points, [("tetra", mesh.cells)]))
    assert load_mesh(plain).axis is None
    bad = meshio.Mesh(
        mesh.points, [("tetra", mesh.cells)], point_data={n: np.random.rand(mesh.n_nodes, 3) for n in AXIS_ARRAYS}
    )
    meshio.write(tmp_path / "bad.vtu", bad)
    with pytest.raises(MeshError, match="one finite 3-vector at every node"):
        load_mesh(tmp_path / "bad.vtu")


def test_surface_is_recomputed(tmp_path):
    mesh = lv_ellipsoid(600)
    path = tmp_path / "plain.vtu"
    meshio.write(path, meshio.Mesh(mesh.points, [("tetra", mesh.cells)]))
    loaded = load_mesh(path)
    assert list(loaded.node_sets) == ["surface"]
    np.testing.assert_array_equal(loaded.node_sets["surface"], np.unique(boundary_faces(mesh.cells)))


def test_tetra_preferred_and_boundary_markers_ignored(tmp_path):
    mesh = lv_ellipsoid(600)
    path = tmp_path / "marked.vtu"
    markers = [("tetra", mesh.cells), ("triangle", boundary_faces(mesh.cells)), ("vertex", np.array([[0]]))]
    meshio.write(path, meshio.Mesh(mesh.points, markers))
    assert load_mesh(path).n_cells == mesh.n_cells


def test_unused_nodes_are_dropped_and_sets_renumbered(tmp_path):
    points = np.vstack([[9.0, 9, 9], TET])  # node 0 in no cell
    epi = np.array([1, 1, 0, 0, 1], dtype=np.uint8)
    path = tmp_path / "extra.vtu"
    raw = meshio.Mesh(points, [("tetra", np.array([[1, 2, 3, 4]]))], point_data={"epicardium": epi})
    meshio.write(path, raw)
    loaded = load_mesh(path, units="mm")
    np.testing.assert_array_equal(loaded.points, TET)
    np.testing.assert_array_equal(loaded.node_sets["epicardium"], [0, 3])


def test_missing_file(tmp_path):
    with pytest.raises(MeshError, match=r"mesh file not found: .*nothing\.vtu"):
        load_mesh(tmp_path / "nothing.vtu")


def test_broken_file(tmp_path):
    path = tmp_path / "broken.vtu"
    path.write_text("<VTKFile> this is not a mesh")
    with pytest.raises(MeshError, match=r"cannot read mesh file .*broken\.vtu"):
        load_mesh(path)


def test_unknown_format(tmp_path):
    path = tmp_path / "heart.xyz123"
    path.write_text("1 2 3\n")
    with pytest.raises(MeshError, match=r"cannot read mesh file .*heart\.xyz123"):
        load_mesh(path)


def test_no_usable_cells(tmp_path):
    path = tmp_path / "lines.vtu"
    meshio.write(path, meshio.Mesh(TET, [("line", np.array([[0, 1], [1, 2]]))]))
    with pytest.raises(MeshError, match=r"no linear tetrahedra, hexahedra or triangles \(cell types: line\)"):
        load_mesh(path)


def test_mixed_volume_cells(tmp_path):
    points = np.vstack([TET, np.random.default_rng(0).random((8, 3)) + 2])
    cells = [("tetra", np.array([[0, 1, 2, 3]])), ("hexahedron", np.arange(4, 12)[None])]
    path = tmp_path / "mixed.vtu"
    meshio.write(path, meshio.Mesh(points, cells))
    with pytest.raises(MeshError, match=r"mixed cell types are unsupported \(tetra with hexahedron\)"):
        load_mesh(path)


@pytest.mark.parametrize("index", [-2, 7])
def test_cell_index_out_of_range_names_the_cell(tmp_path, index):
    path = tmp_path / "outside.vtu"
    meshio.write(path, meshio.Mesh(TET, [("tetra", np.array([[0, 1, 2, 3], [0, 1, index, 3]]))]))
    with pytest.raises(
        MeshError, match=r"outside\.vtu: cell node index out of range \[0, 4\): 1 cell\(s\), first cell 1"
    ):
        load_mesh(path, units="mm")


def test_invalid_mesh_in_file_names_path_and_problem(tmp_path):
    path = tmp_path / "flipped.vtu"
    meshio.write(path, meshio.Mesh(TET, [("tetra", np.array([[1, 0, 2, 3]]))]))
    with pytest.raises(MeshError, match=r"flipped\.vtu: mesh 'flipped' is invalid: .*negative volume"):
        load_mesh(path, units="mm")


def test_bad_node_mask(tmp_path):
    path = tmp_path / "mask.vtu"
    labels = np.array([0, 1, 2, 1])
    meshio.write(path, meshio.Mesh(TET, [("tetra", np.array([[0, 1, 2, 3]]))], point_data={"base": labels}))
    with pytest.raises(MeshError, match=r"point data 'base' is not a 0/1 node mask"):
        load_mesh(path, units="mm")


def test_tetra_to_surface_format_is_refused(tmp_path):
    with pytest.raises(MeshError, match=r"\.stl files hold no tetrahedra"):
        save_mesh(lv_ellipsoid(600), tmp_path / "lv.stl")


def test_unwritable_path(tmp_path):
    with pytest.raises(MeshError, match="cannot write mesh file"):
        save_mesh(lv_ellipsoid(600), tmp_path / "no" / "such" / "dir" / "lv.vtu")
