"""Labels read from mesh files (facet markers, class arrays) and detection checked against public labelled meshes."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import meshio
import numpy as np
import pytest

from bench.labels import DATA, LABELLED, agreement
from shared.errors import MeshError
from simgen.meshes import get_mesh
from simgen.meshes.io import load_mesh
from simgen.meshes.labels import FENICS_MARKERS, label_agreement
from simgen.meshes.nodesets import detect_heart
from simgen.meshes.rays import rays_hit
from simgen.meshes.resample import resample

#: Every label of every labelled mesh, as it is and resampled, is tagged right on at least this share of its nodes.
SHARE = 0.95
PUBLIC = ["cobiveco-mean-biv", "cardiac-geometries-biv", "ldrb-patient-lv", "cardiac-geometries-lv", "rodero01-lv"]


def unpack(name: str, folder: Path) -> Path:
    path = folder / name
    with gzip.open(DATA / f"{name}.gz", "rb") as src, path.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    return path


@pytest.fixture(scope="module", params=PUBLIC)
def labelled(request):
    return request.param, LABELLED[request.param][1]()


def test_detection_agrees_with_the_file_labels(labelled):
    name, mesh = labelled
    share = agreement(mesh)
    assert len(share) >= 2 and min(share.values()) >= SHARE, (name, share)


def test_detection_agrees_with_the_labels_after_resampling(labelled):
    name, mesh = labelled
    coarse = resample(mesh, 1000, "triangle")  # the labels move with the surface
    share = agreement(coarse)
    assert min(share.values()) >= SHARE, (name, coarse.n_nodes, share)


def test_gmsh_physical_groups_become_node_sets(tmp_path):
    path = unpack("ldrb_patient_lv.msh", tmp_path)
    raw, mesh = meshio.read(path), load_mesh(path)
    assert {"base", "epicardium", "endocardium"} <= set(mesh.node_sets)
    assert "lv_endocardium" not in mesh.node_sets  # an LV alone
    tag = {name: int(value[0]) for name, value in raw.field_data.items()}
    for name, key in [("ENDO", "endocardium"), ("EPI", "epicardium"), ("BASE", "base")]:
        nodes = [np.unique(b.data[v == tag[name]]) for b, v in zip(raw.cells, raw.cell_data["gmsh:physical"])]
        nodes = np.unique(np.concatenate([n for b, n in zip(raw.cells, nodes) if b.type == "triangle"]))
        np.testing.assert_array_equal(mesh.nodes(key), nodes)
    # nodes on the line between two labels belong to both: the base meets both walls
    assert np.intersect1d(mesh.nodes("base"), mesh.nodes("epicardium")).size > 0
    assert np.intersect1d(mesh.nodes("base"), mesh.nodes("endocardium")).size > 0


def test_biv_markers_give_both_ventricles(tmp_path):
    mesh = load_mesh(unpack("cardiac_geometries_biv.msh", tmp_path))
    lv, rv = mesh.nodes("lv_endocardium"), mesh.nodes("rv_endocardium")
    assert lv.size and rv.size and not np.intersect1d(lv, rv).size
    np.testing.assert_array_equal(mesh.nodes("endocardium"), np.union1d(lv, rv))


def _numbered(tmp_path: Path, numbers: dict[str, int], names: bool = False) -> Path:
    """The cardiac-geometries BiV with its markers renumbered (``numbers``: marker name -> number), as .vtu."""
    raw = meshio.read(unpack("cardiac_geometries_biv.msh", tmp_path))
    tag = {int(v[0]): name for name, v in raw.field_data.items() if int(v[1]) == 2}
    tets = np.concatenate([b.data for b in raw.cells if b.type == "tetra"])
    tris = [(b.data, v) for b, v in zip(raw.cells, raw.cell_data["gmsh:physical"]) if b.type == "triangle"]
    faces = np.concatenate([f for f, _ in tris])
    values = np.concatenate([[numbers[tag[int(x)]] for x in v] for _, v in tris])
    cells = [("tetra", tets), ("triangle", faces)]
    data = {"markers": [np.zeros(len(tets), np.int64), values.astype(np.int64)]}
    field = {name: np.array([numbers[name], 2]) for name in numbers} if names else {}
    path = tmp_path / "numbered.msh" if names else tmp_path / "numbered.vtu"
    if names:
        data = {"gmsh:physical": data["markers"], "gmsh:geometrical": data["markers"]}
    meshio.write(path, meshio.Mesh(raw.points, cells, cell_data=data, field_data=field), file_format=None)
    return path


def test_fenics_marker_numbers_without_names(tmp_path):
    fenics = {name: value for value, name in FENICS_MARKERS.items()}
    numbers = {"BASE": fenics["base"], "EPI": fenics["epicardium"], "LV": fenics["lv_endocardium"]}
    numbers["RV"] = fenics["rv_endocardium"]
    mesh = load_mesh(_numbered(tmp_path, numbers))
    reference = load_mesh(unpack("cardiac_geometries_biv.msh", tmp_path))
    for key in ("base", "epicardium", "lv_endocardium", "rv_endocardium"):
        np.testing.assert_array_equal(mesh.nodes(key), reference.nodes(key))


def test_markers_that_cannot_be_mapped_are_refused(tmp_path):
    path = _numbered(tmp_path, {"BASE": 1, "EPI": 2, "LV": 3, "RV": 4})
    with pytest.raises(MeshError, match=r"facet markers 'markers' \[1, 2, 3, 4\] have no names"):
        load_mesh(path)
    renamed = tmp_path / "renamed.msh"
    text = unpack("cardiac_geometries_biv.msh", tmp_path).read_text()
    for k, name in enumerate(["EPI", "BASE", "LV", "RV"]):
        text = text.replace(f'"{name}"', f'"wall{k}"')
    renamed.write_text(text)
    with pytest.raises(MeshError, match="no facet marker 'gmsh:physical' names a heart surface"):
        load_mesh(renamed)


def test_masks_in_the_file_take_precedence_over_unmapped_markers(tmp_path):
    path = _numbered(tmp_path, {"BASE": 1, "EPI": 2, "LV": 3, "RV": 4})
    raw = meshio.read(path)
    for name, value in [("epicardium", 2), ("endocardium", 3)]:
        faces = raw.cells[1].data[raw.cell_data["markers"][1] == value]
        raw.point_data[name] = np.isin(np.arange(len(raw.points)), faces).astype(np.uint8)
    meshio.write(path, raw)
    mesh = load_mesh(path)
    assert mesh.nodes("epicardium").size and "base" not in mesh.node_sets


def test_class_array_of_the_cobiveco_mesh():
    mesh = LABELLED["cobiveco-mean-biv"][1]()
    sizes = {k: mesh.nodes(k).size for k in ("base", "epicardium", "lv_endocardium", "rv_endocardium")}
    assert sum(sizes.values()) == mesh.n_nodes and min(sizes.values()) > 0.01 * mesh.n_nodes


def test_file_labels_replace_detection_and_give_the_axis(tmp_path):
    path = unpack("ldrb_patient_lv.msh", tmp_path)
    mesh = get_mesh(str(path))
    np.testing.assert_array_equal(mesh.nodes("base"), load_mesh(path).nodes("base"))
    _, detected = detect_heart(mesh)
    assert mesh.axis is not None and mesh.axis.direction @ detected.direction > 0.98
    assert abs(mesh.axis.length - detected.length) < 0.1 * detected.length


def test_agreement_counts_the_line_between_labels_for_either():
    mesh = get_mesh("lv", 600, "tetra")
    truth = dict(mesh.node_sets)
    assert label_agreement(mesh, truth, truth) == {"base": 1.0, "epicardium": 1.0, "endocardium": 1.0}
    # base taken for epicardium: strictly right only on the base nodes the file's epicardium holds too
    base = truth["base"]
    taken = {
        "epicardium": np.union1d(truth["epicardium"], base),
        "endocardium": np.setdiff1d(truth["endocardium"], base),
        "base": np.array([], np.int64),
    }
    on_epicardium = np.isin(base, truth["epicardium"]).mean()
    assert 0 < on_epicardium < 1
    assert label_agreement(mesh, truth, taken, near=False)["base"] == pytest.approx(on_epicardium)
    assert label_agreement(mesh, truth, taken)["base"] == 1.0  # the rest are one edge from the epicardium


def test_rays_through_the_grid_agree_with_testing_every_triangle():
    mesh = get_mesh("biv", 800, "triangle")
    tris = mesh.points[mesh.cells]
    rng = np.random.default_rng(1)
    origins = rng.uniform(mesh.points.min(axis=0) - 5, mesh.points.max(axis=0) + 5, size=(400, 3))
    directions = rng.normal(size=(400, 3))
    brute = np.array([_any_hit(o, d, tris) for o, d in zip(origins, directions)])
    np.testing.assert_array_equal(rays_hit(origins, directions, tris), brute)
    assert 0.2 < brute.mean() < 0.9


def _any_hit(o: np.ndarray, d: np.ndarray, tris: np.ndarray) -> bool:
    """Moller-Trumbore against every triangle at once."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    s = o - tris[:, 0]
    u = np.einsum("ij,ij->i", s, h) / det
    q = np.cross(s, e1)
    v = q @ d / det
    t = np.einsum("ij,ij->i", e2, q) / det
    return bool((ok & (u >= 0) & (u <= 1) & (v >= 0) & (u + v <= 1) & (t > 0)).any())


def test_a_stray_class_value_is_unlabelled_and_cell_classes_come_first(tmp_path, caplog):
    from simgen.meshes.shipped import unpacked

    with unpacked("cobiveco-mean-biv") as path:
        raw = meshio.read(path)
    classes = np.asarray(raw.point_data["class"]).reshape(-1).astype(np.int64)
    triangles = raw.cells[0].data
    stray = classes.copy()
    stray[17] = 7  # one node of 24,991 holds no class
    meshio.write(
        tmp_path / "stray.vtu", meshio.Mesh(raw.points, [("triangle", triangles)], point_data={"class": stray})
    )
    with caplog.at_level("WARNING", logger="simgen.meshes"):
        mesh = load_mesh(tmp_path / "stray.vtu")
    assert "point data 'class': 1 of 24991 nodes hold no class of [1, 2, 3, 4] (values [7])" in caplog.text
    assert not any(17 in mesh.nodes(k) for k in ("base", "epicardium", "endocardium"))
    per_triangle = classes[triangles].min(axis=1)  # a clean cell array beside the stray point array
    both = meshio.Mesh(
        raw.points, [("triangle", triangles)], point_data={"class": stray}, cell_data={"class": [per_triangle]}
    )
    meshio.write(tmp_path / "both.vtu", both)
    from_cells = load_mesh(tmp_path / "both.vtu")
    base = np.unique(triangles[per_triangle == 1])
    np.testing.assert_array_equal(from_cells.nodes("base"), base)
    noisy = classes.copy()
    noisy[: len(noisy) // 10] = 9  # a tenth of the nodes: no class array
    meshio.write(
        tmp_path / "noisy.vtu", meshio.Mesh(raw.points, [("triangle", triangles)], point_data={"class": noisy})
    )
    with pytest.raises(MeshError, match="point data 'class' holds classes \\[1, 2, 3, 4, 9\\]"):
        load_mesh(tmp_path / "noisy.vtu")
