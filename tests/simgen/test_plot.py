"""Activation and tissue maps render headless to valid, non-trivial PNG files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.errors import InputError
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.plot import plot_activation_maps, plot_tissue, surface_triangles

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tet() -> Mesh:
    return lv_ellipsoid(2000, "tetra")


def _synthetic(mesh: Mesh, stims: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Activation = distance from the stimulus / 0.6 mm/ms; a spherical scar never activates."""
    act = np.stack([np.linalg.norm(mesh.points - mesh.points[s], axis=1) / 0.6 for s in stims])
    r = np.linalg.norm(mesh.points - np.array([30.0, 10.0, -10.0]), axis=1)
    act[:, r < 15] = np.nan
    label = np.select([r < 15, r < 22], [2, 1], 0).astype(np.int8)
    return act, label


def _assert_png(path: Path, min_bytes: int = 20_000) -> None:
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC)
    assert len(data) > min_bytes


def test_surface_triangles(tet: Mesh) -> None:
    faces = surface_triangles(tet)
    assert faces.shape[1] == 3
    np.testing.assert_array_equal(np.unique(faces), tet.nodes("surface"))
    tri = lv_ellipsoid(600, "triangle")
    assert surface_triangles(tri) is tri.cells


def test_activation_maps_png(tet: Mesh, tmp_path: Path) -> None:
    stims = [int(tet.nodes("epicardium")[0]), int(tet.nodes("epicardium")[300])]
    act, _ = _synthetic(tet, stims)
    path = tmp_path / "activation.png"
    plot_activation_maps(tet, act, ["apex", "lateral"], path, stim_nodes=stims)
    _assert_png(path)


def test_activation_maps_triangle_mesh_all_nan_row(tmp_path: Path) -> None:
    tri = lv_ellipsoid(800, "triangle")
    act, _ = _synthetic(tri, [0])
    act = np.vstack([act, np.full(tri.n_nodes, np.nan)])
    path = tmp_path / "tri.png"
    plot_activation_maps(tri, act, ["paced", "blocked"], path, units="a.u.")
    _assert_png(path)


def test_tissue_png(tet: Mesh, tmp_path: Path) -> None:
    _, label = _synthetic(tet, [0])
    assert set(np.unique(label)) == {0, 1, 2}
    path = tmp_path / "tissue.png"
    plot_tissue(tet, label, path, title="one scar")
    _assert_png(path, min_bytes=10_000)


def test_bad_inputs(tet: Mesh, tmp_path: Path) -> None:
    act = np.zeros((2, tet.n_nodes))
    with pytest.raises(InputError, match="shape"):
        plot_activation_maps(tet, act[:, :-1], ["a", "b"], tmp_path / "x.png")
    with pytest.raises(InputError, match="titles"):
        plot_activation_maps(tet, act, ["a"], tmp_path / "x.png")
    with pytest.raises(InputError, match="stim_nodes"):
        plot_activation_maps(tet, act, ["a", "b"], tmp_path / "x.png", stim_nodes=[0, tet.n_nodes])
    with pytest.raises(InputError, match="labels"):
        plot_tissue(tet, np.full(tet.n_nodes, 4), tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()
