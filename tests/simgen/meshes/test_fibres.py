"""Rule-based fibres on the procedural LV: the helix angle follows the rule through the wall (measured in a
frame made from the geometry alone), fibres are unit vectors tangent to the surfaces, files carry them."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from simgen.meshes import save_mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fibres import ldrb_fibres, ldrb_frames, node_gradients, ventricular_coordinates
from simgen.meshes.io import load_mesh
from simgen.meshes.topology import boundary_faces
from simgen.tissue import longitudinal_angular


@pytest.fixture(scope="module")
def lv():
    mesh = get_mesh("lv", 5000, "tetra")
    fibres, coordinates = ldrb_fibres(mesh)
    return mesh, fibres, coordinates["transmural"]


def helix_angles(points: np.ndarray, fibres: np.ndarray) -> np.ndarray:
    """Degrees from the circumferential direction around the z axis towards +z, in (-90, 90]."""
    ec = np.cross([0.0, 0.0, 1.0], points)
    ec /= np.linalg.norm(ec, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0]) - ec[:, 2:3] * ec
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    angle = np.degrees(np.arctan2(np.einsum("nd,nd->n", fibres, up), np.einsum("nd,nd->n", fibres, ec)))
    return (angle + 90.0) % 180.0 - 90.0


def test_the_helix_angle_follows_the_rule_through_the_wall(lv):
    """+60 at the endocardium, -60 at the epicardium, linear in the transmural coordinate: within 5 degrees at
    every node of the mid-ventricle (measured mean 0.6-0.9, max 4.7)."""
    mesh, fibres, d = lv
    mid = (mesh.points[:, 2] > -45.0) & (mesh.points[:, 2] < -5.0)
    error = np.abs((helix_angles(mesh.points, fibres) - (60.0 - 120.0 * d) + 90.0) % 180.0 - 90.0)
    interior = ~np.isin(np.arange(mesh.n_nodes), mesh.nodes("surface"))
    for name, nodes in (("endo", mesh.nodes("endocardium")), ("epi", mesh.nodes("epicardium"))):
        on = np.isin(np.arange(mesh.n_nodes), nodes) & mid
        assert on.sum() > 100 and error[on].max() < 5.0, name
        assert np.all(d[nodes] == (0.0 if name == "endo" else 1.0))
    assert (interior & mid).sum() > 100 and error[interior & mid].max() < 5.0
    assert np.percentile(d[interior & mid], 5) < 0.45 < 0.55 < np.percentile(d[interior & mid], 95)


def test_fibres_are_unit_vectors_tangent_to_the_surfaces(lv):
    mesh, fibres, _ = lv
    np.testing.assert_allclose(np.linalg.norm(fibres, axis=1), 1.0, atol=1e-12)
    tris, p = boundary_faces(mesh.cells), mesh.points
    normal = np.zeros_like(p)
    np.add.at(
        normal,
        tris.ravel(),
        np.repeat(np.cross(p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]]), 3, axis=0),
    )
    walls = np.setdiff1d(np.union1d(mesh.nodes("endocardium"), mesh.nodes("epicardium")), mesh.nodes("base"))
    normal = normal[walls] / np.linalg.norm(normal[walls], axis=1, keepdims=True)
    off = np.degrees(np.arcsin(np.abs(np.einsum("nd,nd->n", fibres[walls], normal))))
    assert off.max() < 5.0 and off.mean() < 1.0  # measured 2.0 and 0.3


def test_mesh_files_carry_fibres_as_they_are(lv, tmp_path):
    import dataclasses

    mesh, fibres, _ = lv
    path = save_mesh(dataclasses.replace(mesh, fibres=fibres), tmp_path / "lv.vtu")
    np.testing.assert_allclose(load_mesh(path).fibres, fibres, atol=1e-12)
    assert get_mesh(str(path)).fibres is not None  # used as it is: kept
    same = save_mesh(dataclasses.replace(mesh, fibres=fibres), tmp_path / "same.vtu", point_data={"fiber": -fibres})
    np.testing.assert_allclose(load_mesh(same).fibres, fibres, atol=1e-12)  # two names, one axial field: read
    turned = np.roll(fibres, 1, axis=1)
    other = save_mesh(dataclasses.replace(mesh, fibres=fibres), tmp_path / "two.vtu", point_data={"fiber": turned})
    with pytest.raises(MeshError, match="point data 'fibre' and 'fiber' both give a direction per node and differ"):
        load_mesh(other)


def test_biventricular_fibres_follow_the_rule_on_both_walls_and_the_septum():
    """Medians within 3 degrees, the central 80% within 8, in the frame around the LV's axis (which the RV's
    walls follow only roughly): +60 on the LV endocardium (free wall and septum) and the RV free wall's, -60 on
    the LV free wall's epicardium; on the septum's RV side (its middle: the RV endocardium wraps round at
    the junctions) -60 in this frame (+60 from the RV cavity's side)."""
    mesh = get_mesh("biv", 5000, "tetra")
    fibres, coordinates = ldrb_fibres(mesh)
    assert sorted(coordinates) == ["apicobasal", "rv_share", "transmural"]
    np.testing.assert_allclose(np.linalg.norm(fibres, axis=1), 1.0, atol=1e-12)
    p, angle = mesh.points, helix_angles(mesh.points, fibres)
    mid, radius = (p[:, 2] > -45.0) & (p[:, 2] < -5.0), np.hypot(p[:, 0], p[:, 1])
    node = np.arange(mesh.n_nodes)
    lv, rv, epi = (np.isin(node, mesh.nodes(s)) for s in ("lv_endocardium", "rv_endocardium", "epicardium"))
    regions = {
        "LV endocardium": (lv & mid, 60.0),
        "epicardium, LV free wall": (epi & mid & (p[:, 0] < 0.0), -60.0),
        "RV free wall endocardium": (rv & mid & (radius > np.percentile(radius[rv], 60)), 60.0),
        "septum, RV side": (rv & mid & (radius < np.percentile(radius[rv], 30)) & (np.abs(p[:, 1]) < 15.0), -60.0),
    }
    for name, (where, expected) in regions.items():
        off = angle[where] - expected
        assert where.sum() > 50 and abs(np.median(off)) < 3.0, name
        assert np.all(np.abs(np.percentile(off, [10, 90])) < 8.0), name


def test_what_the_rule_cannot_take_is_refused():
    with pytest.raises(MeshError, match="need a volume"):
        ldrb_fibres(get_mesh("lv", 1000, "triangle"))


def test_simgen_mesh_writes_fibres_that_simulate_conducts_along(tmp_path):
    from typer.testing import CliRunner

    from simgen.cli import app

    runner = CliRunner()
    path = tmp_path / "lv.vtu"
    assert runner.invoke(app, ["mesh", str(path), "--nodes", "2000", "--fibres"]).exit_code == 0
    assert load_mesh(path).fibres is not None and (tmp_path / "lv.fibres.png").stat().st_size > 10_000
    import meshio

    written = meshio.read(path).point_data
    assert {"fibre", "transmural", "apicobasal"} <= set(written) and written["transmural"].max() == 1.0
    latest = {}
    for ratio in ("1", "4"):
        out = tmp_path / f"r{ratio}"
        result = runner.invoke(app, ["simulate", str(out), "--mesh", str(path), "--anisotropy", ratio, "--sites", "0"])
        assert result.exit_code == 0, result.output
        latest[ratio] = np.nanmax(np.load(out / "simulation.npz")["activation_ms"])
    assert latest["4"] > 1.2 * latest["1"]  # slower across the fibres: the wall takes longer to activate


def test_rotational_coordinate_turns_around_the_axis_from_the_rv():
    mesh = get_mesh("biv", 1500, "tetra")
    coordinates = ventricular_coordinates(mesh)
    assert sorted(coordinates) == ["apicobasal", "rotational", "rv_share", "transmural"]
    rotational = coordinates["rotational"]
    np.testing.assert_allclose(np.degrees(rotational), longitudinal_angular(mesh)[1], atol=1e-9)  # the AHA angle
    assert rotational.min() < -0.95 * np.pi and rotational.max() > 0.95 * np.pi
    rv = rotational[mesh.nodes("rv_endocardium")]
    assert abs(np.angle(np.exp(1j * rv).mean())) < np.radians(20)  # the RV lies at angle 0


def test_sheets_turn_out_of_the_wall_by_the_sheet_angle(lv, tmp_path):
    """Sheets are unit vectors orthogonal to the fibres, at beta(d) = -65 (1 - d) + 25 d degrees out of the
    wall's tangent plane (the plane normal to grad d): within 2 degrees at the mid-ventricle; files carry them."""
    import dataclasses

    mesh, _, d = lv
    frames = ldrb_frames(mesh)
    np.testing.assert_allclose(np.einsum("nd,nd->n", frames.fibres, frames.sheets), 0.0, atol=1e-12)
    normal = node_gradients(mesh, d)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    out = np.degrees(np.arcsin(np.clip(np.einsum("nd,nd->n", frames.sheets, normal), -1.0, 1.0)))
    mid = (mesh.points[:, 2] > -45.0) & (mesh.points[:, 2] < -5.0)
    assert np.abs(out - (-65.0 * (1.0 - d) + 25.0 * d))[mid].max() < 2.0
    path = save_mesh(dataclasses.replace(mesh, fibres=frames.fibres, sheets=frames.sheets), tmp_path / "lv.vtu")
    np.testing.assert_allclose(load_mesh(path).sheets, frames.sheets, atol=1e-12)
