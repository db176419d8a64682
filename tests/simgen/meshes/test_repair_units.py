"""Mesh files as users bring them: units, orientation, hexahedra, unused nodes, degenerate cells, resampling."""

from __future__ import annotations

import itertools
import logging

import meshio
import numpy as np
import pytest

from shared.errors import MeshError
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.io import load_mesh, save_mesh
from simgen.meshes.repair import split_hexahedra
from simgen.meshes.resample import hausdorff_distance, resample, tetrahedralise
from simgen.meshes.slab import slab
from simgen.meshes.topology import signed_volumes
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
    with pytest.raises(
        MeshError, match=r"cannot infer the length unit from the mesh extent 1\.\d+ .*--units mm\|cm\|m"
    ):
        load_mesh(path)
    assert load_mesh(path, units="m").points.max() > 0  # a given unit settles it


def test_units_are_inferred_from_the_nodes_in_cells(tmp_path):
    stray = np.vstack([LV.points, [[5000.0, 0.0, 0.0]]])  # a node in no cell, far away
    path = tmp_path / "stray.ply"
    meshio.write(path, meshio.Mesh(stray, [("triangle", LV.cells)]))
    loaded = load_mesh(path)
    assert loaded.n_nodes == LV.n_nodes and np.ptp(loaded.points, axis=0).max() < 250  # mm, the stray dropped


def test_a_mesh_that_is_no_heart_is_read_in_mm(tmp_path):
    path = tmp_path / "slab.ply"  # under 2 units long, no unit metadata: no heart size to infer from
    meshio.write(path, meshio.Mesh(LV.points * 0.02, [("triangle", LV.cells)]))
    with pytest.raises(MeshError, match="cannot infer the length unit"):
        load_mesh(path)
    np.testing.assert_allclose(load_mesh(path, heart=False).points, LV.points * 0.02)


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
    assert resample(coarse, 1050, "triangle") is coarse  # on target, no angle below 20 degrees: kept
    finer = resample(coarse, 1600, "triangle")  # refined
    assert abs(finer.n_nodes / 1600 - 1) <= 0.1 and hausdorff_distance(fine, finer) < 2.0


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
    with pytest.raises(MeshError, match="TetGen could not fill the surface"):  # asked for by name: no fallback
        tetrahedralise(points, tris, 40, "overlap", filler="tetgen")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
    filled, tets = tetrahedralise(points, tris, 40, "overlap")  # auto: fTetWild where TetGen refuses
    assert len(tets) and sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


# Unit cube corners in VTK hexahedron order (bottom 0-3, top 4-7).
CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])


def cube_symmetries() -> np.ndarray:
    """The 48 relabellings of a hexahedron's corners by the rotations and reflections of the cube, (48, 8)."""
    found = []
    for axes in itertools.permutations(range(3)):
        for flip in itertools.product((0, 1), repeat=3):
            moved = np.abs(CUBE[:, axes] - np.array(flip))  # corner i goes to corner perm[i]
            found.append([int(np.flatnonzero((CUBE == m).all(axis=1))[0]) for m in moved])
    return np.array(found)


def permuted_hex_grid(shape=(4, 3, 2), h=(15.0, 20.0, 25.0), seed=0) -> tuple[np.ndarray, np.ndarray]:
    """A structured hexahedral grid, nodes numbered at random, every hexahedron listing its corners in a random
    order of the cube's symmetry."""
    n = np.array(shape) + 1
    axes = [np.arange(k) * step for k, step in zip(n, h, strict=True)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange(len(points)).reshape(n)
    corner = index[:-1, :-1, :-1].ravel()
    hexes = corner[:, None] + (CUBE * [n[1] * n[2], n[2], 1]).sum(axis=1)
    rng = np.random.default_rng(seed)
    number = rng.permutation(len(points))  # node i becomes number[i]
    symmetry = cube_symmetries()[rng.integers(0, 48, len(hexes))]
    renumbered = np.empty_like(points)
    renumbered[number] = points
    return renumbered, number[np.take_along_axis(hexes, symmetry, axis=1)]


def assert_tiles_the_box(points, tets, volume):
    """Positive tetrahedra filling ``volume``, conforming, with a closed 2-manifold boundary on the box."""
    assert (signed_volumes(points, tets) > 0).all()
    assert signed_volumes(points, tets).sum() == pytest.approx(volume)
    faces = np.sort(tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    triangles, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}  # interior faces in exactly two tetrahedra
    boundary = triangles[counts == 1]
    on_box = (points[boundary] == points.min(axis=0)) | (points[boundary] == points.max(axis=0))
    assert on_box.all(axis=1).any(axis=1).all()  # every boundary triangle lies in a side of the box
    _, edge_counts = np.unique(
        np.sort(boundary[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1), axis=0, return_counts=True
    )
    assert (edge_counts == 2).all()


def test_hexahedra_in_any_node_order_split_conformingly():
    points, hexes = permuted_hex_grid()
    tets = split_hexahedra(points, hexes, "grid")
    assert len(tets) in range(5 * len(hexes), 6 * len(hexes) + 1)
    assert_tiles_the_box(points, tets, 60.0 * 60.0 * 50.0)


def test_every_node_numbering_of_a_hexahedron_is_tiled():
    """All 8! orders of a cube's global node numbers: each cube is tiled by 5 or 6 tetrahedra."""
    orders = np.array(list(itertools.permutations(range(8))))
    hexes = 8 * np.arange(len(orders))[:, None] + orders  # local corner i has the orders[k, i]-th smallest number
    points = np.empty((hexes.size, 3))
    points[hexes.ravel()] = np.tile(CUBE, (len(orders), 1))
    tets = split_hexahedra(points, hexes, "cubes")
    owner = tets[:, 0] // 8
    volume = signed_volumes(points, tets)
    assert (volume > 0).all() and np.isin(np.bincount(owner), (5, 6)).all()
    np.testing.assert_allclose(np.bincount(owner, volume), 1.0)
    faces = np.sort(tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    triangles, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2} and (counts == 1).sum() == 12 * len(orders)
    boundary = triangles[counts == 1]
    corners = points[boundary]
    in_side = (corners == corners[:, :1]).all(axis=1)  # (triangle, axis): the side of its cube it lies in
    assert (in_side.sum(axis=1) == 1).all()
    axis = in_side.argmax(axis=1)
    cube = points.reshape(-1, 8, 3)[boundary[:, 0] // 8]
    side = cube[np.arange(len(boundary)), :, axis] == corners[np.arange(len(boundary)), 0, axis][:, None]
    smallest = 8 * (boundary[:, 0] // 8) + side.argmax(axis=1)  # the side's smallest node number
    assert (boundary == smallest[:, None]).any(axis=1).all()  # each side cut along its diagonal through it


def test_permuted_hexahedral_grid_loads(tmp_path, caplog):
    points, hexes = permuted_hex_grid(shape=(3, 2, 2), seed=1)
    path = tmp_path / "grid.vtu"
    meshio.write(path, meshio.Mesh(points, [("hexahedron", hexes)]))
    with caplog.at_level(logging.WARNING, logger="simgen.meshes"):
        mesh = load_mesh(path, units="mm")
    assert mesh.cell_type == "tetra" and mesh.n_nodes == len(points)
    assert_tiles_the_box(mesh.points, mesh.cells, 45.0 * 40.0 * 50.0)
    assert f"split {len(hexes)} hexahedra into {mesh.n_cells} tetrahedra" in caplog.text


@pytest.mark.parametrize("units", ["m", "mm"])
def test_a_heart_of_no_hearts_size_is_refused_with_its_size(tmp_path, units):
    from simgen.meshes.heart import load_heart

    lv = lv_ellipsoid(1000)
    scale = 1.0 if units == "m" else 1e-3  # a mm file declared in metres: 80 m; a m file read as mm: 0.08 mm
    path = tmp_path / "heart.vtu"
    meshio.write(path, meshio.Mesh(lv.points * scale, [("tetra", lv.cells)]))
    with pytest.raises(MeshError, match=r"read as a heart .* mm across, and hearts span about 40-250 mm"):
        load_heart(path, None, None, units=units)
    assert load_heart(path, None, None, units="m" if units == "mm" else "mm").n_nodes == lv.n_nodes
    with pytest.raises(MeshError, match="n_nodes=5 outside the supported range 200..200000"):
        load_heart(path, 5, None, units="m" if units == "mm" else "mm")
