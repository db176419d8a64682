"""Tetrahedral fillers: fTetWild fills a surface merged from overlapping parts; ``auto`` keeps TetGen's meshes."""

from __future__ import annotations

import numpy as np
import pytest

from bench.fill import biv_union_volume, merged_biv, merged_surface, union_volume
from shared.errors import ConfigError, MeshError
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fillers import resolve_filler, tetgen_available
from simgen.meshes.folds import crossing_triangles
from simgen.meshes.quality import mesh_quality
from simgen.meshes.resample import resample
from simgen.meshes.topology import extract_surface, signed_volumes
from simgen.meshes.validate import validate_mesh
from simgen.store.spec import MeshEntry

needs_tetgen = pytest.mark.skipif(not tetgen_available(), reason="TetGen (the tetra extra) is not installed")


#: Nodes of each LV of the merged surface (bench/fill.py measures 3,000-node parts at 1k, 2k and 5k nodes).
PARTS = 1500


@pytest.fixture(scope="module")
def merged():
    return merged_surface(PARTS)


def test_a_surface_merged_from_crossing_parts_fills_with_ftetwild(merged):
    """700 nodes within 15% (measured +4.0%), a valid mesh of positive tetrahedra, the volume of the union of
    the parts (not of either, not their sum) within 5% (measured 0.981), quality reported."""
    assert len(crossing_triangles(merged.points, merged.cells)) > 100
    mesh = validate_mesh(resample(merged, 700, "tetra"))
    assert abs(mesh.n_nodes / 700 - 1) <= 0.15
    volumes = signed_volumes(mesh.points, mesh.cells)
    assert (volumes > 0).all()
    assert volumes.sum() == pytest.approx(union_volume(PARTS), rel=0.05)
    assert mesh_quality(mesh).min_angle > 5.0


@needs_tetgen
def test_auto_falls_back_to_ftetwild_when_tetgen_refuses_a_biv_merged_from_three_parts(monkeypatch, caplog):
    """The three-part BiV of bench/fill.py, its crossings hidden from ``auto``'s check: TetGen refuses it and
    fTetWild fills it, 700 nodes within 15%, a valid closed volume of the union of the parts within 5%."""
    import simgen.meshes.fillers as fillers

    biv = merged_biv(PARTS)
    monkeypatch.setattr(fillers, "crossing_triangles", lambda points, tris: ())
    assert resolve_filler("auto", biv.points, biv.cells, "biv") == "tetgen"
    with caplog.at_level("WARNING", logger="simgen.meshes"):
        mesh = validate_mesh(resample(biv, 700, "tetra"))
    assert "TetGen could not fill the surface" in caplog.text and "filling it with fTetWild instead" in caplog.text
    assert abs(mesh.n_nodes / 700 - 1) <= 0.15
    assert signed_volumes(mesh.points, mesh.cells).sum() == pytest.approx(biv_union_volume(PARTS), rel=0.05)
    with pytest.raises(MeshError, match="TetGen could not fill"):  # asked for by name: no fallback
        resample(biv, 700, "tetra", "tetgen")


@needs_tetgen
def test_auto_keeps_tetgen_on_clean_surfaces_and_names_ftetwild_where_tetgen_cannot(merged):
    clean = extract_surface(get_mesh("lv", 2000, kind="triangle"))
    assert resolve_filler(None, clean.points, clean.cells, "lv") == "tetgen"
    assert resolve_filler("auto", merged.points, merged.cells, "merged") == "ftetwild"
    with pytest.raises(MeshError, match="crosses itself.*use filler 'ftetwild'"):
        resolve_filler("tetgen", merged.points, merged.cells, "merged")
    with pytest.raises(MeshError, match="unknown filler 'gmsh'"):
        resolve_filler("gmsh", clean.points, clean.cells, "lv")


def test_filler_is_a_file_key_out_of_the_spec_hash():
    assert MeshEntry("m", "real:tof-biv", 1000, filler="ftetwild").filler == "ftetwild"
    with pytest.raises(ConfigError, match="apply to mesh files and real meshes"):
        MeshEntry("m", "lv", 1000, filler="ftetwild")
    with pytest.raises(ConfigError, match="filler 'gmsh' is not one of"):
        MeshEntry("m", "real:tof-biv", 1000, filler="gmsh")
    with pytest.raises(MeshError, match="takes no units, landmarks, node_set_arrays, filler"):
        get_mesh("lv", 1000, filler="ftetwild")


def test_ftetwild_volumes_keep_their_largest_piece_lose_their_pinches_and_must_be_closed():
    from simgen.meshes.resample import _closed_volume, _largest_piece, _manifold
    from simgen.meshes.validate import non_manifold_nodes

    lv = get_mesh("lv", 400, kind="tetra")
    n = lv.n_nodes
    speck = np.vstack([lv.points, lv.points[lv.cells[0]] + 500.0])  # a loose tetrahedron far away
    points, tets = _largest_piece(speck, np.vstack([lv.cells, [[n, n + 1, n + 2, n + 3]]]))
    assert len(points) == n and len(tets) == len(lv.cells)
    apex = int(lv.nodes("surface")[0])  # a tetrahedron touching the volume at one surface node: a pinch
    outward = lv.points[apex] - lv.points.mean(axis=0)
    tip = lv.points[apex] + 0.1 * outward + 3.0 * np.eye(3)  # three corners just outside, 3 mm apart
    pinched = np.vstack([lv.points, tip])
    cells = np.vstack([lv.cells, [[apex, n, n + 1, n + 2]]])
    assert apex in non_manifold_nodes(cells)
    points, tets = _manifold(pinched, cells)
    assert len(points) == n and len(tets) == len(lv.cells) and not len(non_manifold_nodes(tets))
    with pytest.raises(MeshError, match="fTetWild's volume is not a valid closed volume .*duplicate cell"):
        _closed_volume(lv.points, np.vstack([lv.cells, lv.cells[:1]]), "lv")
