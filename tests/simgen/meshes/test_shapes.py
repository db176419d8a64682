"""Physiological shape parameters: defaults, ranges, and the geometry they describe."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from shared.errors import ConfigError, MeshError
from simgen.meshes.biventricular import BiVGeometry
from simgen.meshes.ellipsoid import LVGeometry, lv_ellipsoid
from simgen.meshes.shapes import BiVShape, LVShape, parameter_ranges, shape_from_params

RANGES = parameter_ranges(BiVShape)


def test_defaults_give_the_default_geometries():
    assert LVShape().geometry() == LVGeometry()
    biv, default = BiVShape().geometry(), BiVGeometry()
    assert biv.lv == default.lv
    np.testing.assert_allclose(biv.rv_centre, default.rv_centre, atol=1e-12)
    np.testing.assert_allclose(biv.rv_endo_axes, default.rv_endo_axes, atol=0.1)
    np.testing.assert_allclose(np.subtract(biv.rv_epi_axes, biv.rv_endo_axes), 5.0)


def test_every_default_lies_in_its_range():
    shape = BiVShape()
    assert set(RANGES) > set(parameter_ranges(LVShape))
    for name, r in RANGES.items():
        assert r.lo <= getattr(shape, name) <= r.hi, name


@pytest.mark.parametrize("name", list(RANGES))
@pytest.mark.parametrize("side", ["below", "above"])
def test_out_of_range_is_refused_naming_parameter_and_range(name, side):
    r = RANGES[name]
    value = r.lo - 1.0 if side == "below" else r.hi + 1.0
    message = rf"BiV shape: {name} = {value!r}.* outside the physiological range {r.lo:g}\.\.{r.hi:g}"
    with pytest.raises(MeshError, match=message):
        BiVShape(**{name: value})


def test_nan_and_bad_seed_are_refused():
    with pytest.raises(MeshError, match="LV shape: wall_thickness = nan"):
        LVShape(wall_thickness=float("nan"))
    with pytest.raises(MeshError, match="bump_seed must be an integer >= 0"):
        LVShape(bump_seed=-1)


def test_params_round_trip_and_strict_parsing():
    shape = BiVShape(wall_thickness=9, rv_wrap_angle=150.0, bump_amplitude=1.0, bump_seed=4)
    assert shape_from_params("biv", shape.params()) == shape
    assert shape_from_params("lv", {"wall_thickness": 9}).wall_thickness == 9.0
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['rv_width'\]"):
        shape_from_params("lv", {"rv_width": 20.0})
    with pytest.raises(ConfigError, match="shape_params.length: expected a number"):
        shape_from_params("lv", {"length": "long"})
    with pytest.raises(MeshError, match="procedural source"):
        shape_from_params("heart.vtu", {})


def test_lv_geometry_follows_the_parameters():
    shape = LVShape(
        length=92.0,
        endo_radius=22.0,
        wall_thickness=12.0,
        apex_thickness=6.0,
        base_height=20.0,
        eccentricity_index=1.2,
        apex_offset=5.0,
        apex_offset_angle=90.0,
    )
    geom = shape.geometry()
    assert geom.epi_long + geom.base_z == 92.0 and geom.base_z == 20.0
    assert geom.epi_short - geom.endo_short == 12.0 and geom.epi_long - geom.endo_long == 6.0
    np.testing.assert_allclose(geom.radii(0), (22.0 / 1.2, 22.0, 66.0))
    np.testing.assert_allclose(geom.radii(1)[0] - geom.radii(0)[0], 12.0)  # uniform wall
    np.testing.assert_allclose(geom.apex_offset, (0.0, 5.0), atol=1e-12)
    np.testing.assert_allclose(geom.long_axis().apex, (0.0, 5.0, -72.0), atol=1e-12)


def test_eccentricity_flattens_the_septal_axis():
    geom = LVShape(eccentricity_index=1.25).geometry()
    mesh = lv_ellipsoid(1000, geometry=geom)
    p = mesh.points[mesh.node_sets["endocardium"]]
    rx, ry, rz = geom.radii(0)
    level = (p[:, 0] / rx) ** 2 + (p[:, 1] / ry) ** 2 + (p[:, 2] / rz) ** 2
    np.testing.assert_allclose(level, 1.0, atol=1e-9)
    assert rx == pytest.approx(ry / 1.25)


def insertion_angle(geom: BiVGeometry) -> float:
    """Full angle (deg) between the RV insertion points on the LV epicardial equator."""
    ex, ey, _ = geom.lv.radii(1)
    cx, ax, ay = geom.rv_centre[0], geom.rv_endo_axes[0], geom.rv_endo_axes[1]

    def on_rv(a: float) -> float:
        rho = 1 / np.hypot(np.cos(a) / ex, np.sin(a) / ey)
        return ((rho * np.cos(a) - cx) / ax) ** 2 + (rho * np.sin(a) / ay) ** 2 - 1

    return 2 * np.degrees(brentq(on_rv, 1e-6, np.pi - 1e-6))


@pytest.mark.parametrize(
    "params",
    [
        {},
        dict(rv_width=26.0, rv_wrap_angle=185.0, eccentricity_index=1.2),
        dict(rv_width=14.0, rv_wrap_angle=140.0, rv_length=0.7, length=72.0, rv_wall_thickness=3.0),
    ],
)
def test_rv_geometry_follows_the_parameters(params):
    shape = BiVShape(**params)
    geom = shape.geometry()
    assert insertion_angle(geom) == pytest.approx(shape.rv_wrap_angle, abs=1e-6)
    assert geom.rv_centre[0] + geom.rv_endo_axes[0] - geom.lv.radii(1)[0] == pytest.approx(shape.rv_width)
    assert geom.base_z + geom.rv_endo_axes[2] == pytest.approx(shape.rv_length * shape.length)
    np.testing.assert_allclose(np.subtract(geom.rv_epi_axes, geom.rv_endo_axes), shape.rv_wall_thickness)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(eccentricity_index=0.0), "eccentricity_index must be positive"),
        (dict(bumps=(1.0, 2.0)), "do not fill whole degrees"),
        (dict(apex_offset=(1.0,)), "apex_offset must be"),
    ],
)
def test_lv_geometry_checks_its_deformations(kwargs, match):
    with pytest.raises(MeshError, match=match):
        LVGeometry(**kwargs)


def test_docs_list_every_parameter_with_its_ranges():
    text = (Path(__file__).resolve().parents[3] / "docs" / "anatomies.md").read_text()
    for name, r in RANGES.items():
        sampled = "the range" if r.sampled is None else f"{r.sampled[0]:g} to {r.sampled[1]:g}"
        assert re.search(rf"\| `{name}` \| [^|]+ \| {r.lo:g} to {r.hi:g} \| {sampled} \|", text), name
