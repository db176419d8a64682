"""Mesh files as users bring them: units, orientation, hexahedra, unused nodes, degenerate cells, resampling."""

from __future__ import annotations

import logging

import meshio
import numpy as np
import pytest

from shared.errors import MeshError
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.io import load_mesh, save_mesh
from simgen.meshes.resample import hausdorff_distance, resample, tetrahedralise
from simgen.meshes.slab import slab
from simgen.meshes.validate import mesh_problems

LV = lv_ellipsoid(1500, kind="triangle")


@pytest.mark.parametrize(("unit", "scale"), [("mm", 1.0), ("cm", 0.1), ("m", 0.001)])
def test_units_inferred_from_the_extent(tmp_path, unit, scale, caplog):
    path = tmp_path / f"lv-{unit}.ply"  # no unit metadata
    meshio.write(path, meshio.Mesh(LV.points * scale, [("triangle", LV.cells)]))
    with caplog.at_level(logging.INFO, logger="simgen.meshes"):
        loaded = load_mesh(path)
    np.testing.assert_allclose(loaded.points, LV.points, rtol=1e-12, atol=1e-12)
    assert ("(unit inferred)" in caplog.text) == (unit != "mm")


def test_ambiguous_extent_is_refused(tmp_path):
    path = tmp_path / "small.ply"
    meshio.write(path, meshio.Mesh(LV.points * 0.02, [("triangle", LV.cells)]))  # under 2 units long
    with pytest.raises(MeshError, match=r"cannot infer the length unit from the mesh extent 1\.\d+ .*units = 'mm'"):
        load_mesh(path)
    assert load_mesh(path, units="m").points.max() > 0  # a given unit settles it


def test_file_units_win_over_inference_and_must_agree(tmp_path):
    path = save_mesh(slab(20.0, 10.0, 4.0, 2.0), tmp_path / "slab.vtu")  # 20 mm would be inferred as cm
    assert np.ptp(load_mesh(path).points, axis=0).max() == pytest.approx(20.0)
    with pytest.raises(MeshError, match="the file says its unit is 'mm' but 'cm' was given"):
        load_mesh(path, units="cm")


def test_orientation_repair(tmp_path, caplog):
    assert not mesh_problems(LV)
    flipped = LV.cells.copy()
    flipped[::7] = flipped[::7, ::-1]
    inward = LV.cells[:, ::-1]
    for cells in (flipped, inward):
        path = tmp_path / "lv.vtu"
        meshio.write(path, meshio.Mesh(LV.points, [("triangle", cells)]))
        with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
            loaded = load_mesh(path)
        np.testing.assert_array_equal(loaded.cells, LV.cells)
    assert "consistent with their neighbours" in caplog.text and "to point outward" in caplog.text


def test_a_valid_mesh_is_left_bit_for_bit(tmp_path, caplog):
    path = tmp_path / "lv.vtu"
    meshio.write(path, meshio.Mesh(LV.points, [("triangle", LV.cells)]))
    with caplog.at_level(logging.INFO, logger="simgen.meshes"):
        loaded = load_mesh(path)
    assert loaded.points.tobytes() == LV.points.tobytes() and loaded.cells.tobytes() == LV.cells.tobytes()
    assert caplog.text == ""


def test_hexahedra_are_split_into_tetrahedra(tmp_path, caplog):
    x = np.linspace(0.0, 60.0, 4)
    grid = np.stack(np.meshgrid(x, x, x[:3], indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange(len(grid)).reshape(4, 4, 3)
    corner = index[:-1, :-1, :-1].ravel()
    offsets = [0, 12, 15, 3, 1, 13, 16, 4]  # VTK order: (0,0,0) (1,0,0) (1,1,0) (0,1,0), then z + 1
    hexes = corner[:, None] + np.array(offsets)
    path = tmp_path / "block.vtu"
    meshio.write(path, meshio.Mesh(grid, [("hexahedron", hexes)]))
    with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
        mesh = load_mesh(path)
    assert mesh.cell_type == "tetra" and mesh.n_cells == 6 * len(hexes)
    p = mesh.points[mesh.cells]
    volume = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6
    assert (volume > 0).all() and volume.sum() == pytest.approx(60.0 * 60.0 * 40.0)
    assert f"split {len(hexes)} hexahedra into {6 * len(hexes)} tetrahedra" in caplog.text


def test_unused_nodes_dropped_with_the_mapping_reported(tmp_path, caplog):
    points = np.vstack([[90.0, 0, 0], LV.points])
    path = tmp_path / "extra.vtu"
    meshio.write(path, meshio.Mesh(points, [("triangle", LV.cells + 1)]))
    with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
        loaded = load_mesh(path)
    np.testing.assert_array_equal(loaded.points, LV.points)
    assert (
        "dropped 1 unused node(s) (in no cell) [0]; the other nodes are renumbered old->new: 1->0, 2->1" in caplog.text
    )


def test_degenerate_cells_removed_with_a_note(tmp_path, caplog):
    a, b = LV.cells[0, :2]
    points = np.vstack([LV.points, (LV.points[a] + LV.points[b]) / 2])
    cells = np.vstack([LV.cells, [[a, b, len(LV.points)]]])  # zero area, on a node of its own
    path = tmp_path / "sliver.vtu"
    meshio.write(path, meshio.Mesh(points, [("triangle", cells)]))
    with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
        loaded = load_mesh(path)
    np.testing.assert_array_equal(loaded.cells, LV.cells)
    assert f"removed 1 degenerate cell(s) (zero-area triangle) [{len(LV.cells)}]" in caplog.text
    assert f"dropped 1 unused node(s) (in no cell) [{len(LV.points)}]" in caplog.text


def test_resampling_keeps_the_shape_and_fills_closed_surfaces():
    fine = lv_ellipsoid(6000, kind="triangle")
    coarse = resample(fine, 1000, "triangle")
    assert abs(coarse.n_nodes / 1000 - 1) <= 0.1 and not mesh_problems(coarse)
    assert hausdorff_distance(fine, coarse) < 2.0  # mm, for an 80 mm LV
    volume = resample(fine, 1500, "tetra")
    assert volume.cell_type == "tetra" and abs(volume.n_nodes / 1500 - 1) <= 0.1
    assert {"epicardium", "endocardium", "base"} <= set(volume.node_sets)
    assert resample(coarse, 5000, "triangle") is coarse  # never refined


def test_an_open_surface_is_not_filled():
    lv = lv_ellipsoid(800, kind="triangle")
    open_cells = lv.cells[: len(lv.cells) // 2]
    used = np.unique(open_cells)
    index = np.full(lv.n_nodes, -1)
    index[used] = np.arange(len(used))
    from shared.mesh import Mesh

    half = Mesh(lv.points[used], index[open_cells], {"surface": np.arange(len(used))})
    with pytest.raises(MeshError, match="open triangle surface cannot be filled with tetrahedra"):
        resample(half, 300, "tetra")


def test_a_self_intersecting_surface_is_refused_without_debris(tmp_path, monkeypatch):
    """TetGen writes _skipped.face/.node into the working directory when it fails: none may be left there."""
    pytest.importorskip("tetgen")
    import trimesh

    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([0.5, 0.5, 0.5])  # two overlapping cubes: one surface that intersects itself
    points, tris = np.vstack([a.vertices, b.vertices]), np.vstack([a.faces, b.faces + len(a.vertices)])
    monkeypatch.chdir(tmp_path)
    (tmp_path / "keep.txt").write_text("a user's file")
    with pytest.raises(MeshError, match="TetGen could not fill the surface"):
        tetrahedralise(points, tris, 40, "overlap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
