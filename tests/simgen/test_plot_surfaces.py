"""Side-by-side surface figures of several meshes (e.g. sampled anatomies) render to PNG."""

from __future__ import annotations

import pytest

from shared.errors import InputError
from simgen.meshes import biv_ellipsoid, lv_ellipsoid
from simgen.plot import plot_surfaces

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_plot_surfaces_renders_a_png(tmp_path):
    meshes = [lv_ellipsoid(500), biv_ellipsoid(500, kind="triangle"), lv_ellipsoid(400)]
    path = tmp_path / "surfaces.png"
    plot_surfaces(meshes, ["lv", "biv", "small lv"], path, n_cols=2)
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 20_000


def test_plot_surfaces_needs_one_title_per_mesh(tmp_path):
    with pytest.raises(InputError, match="one per mesh"):
        plot_surfaces([lv_ellipsoid(400)], [], tmp_path / "x.png")
