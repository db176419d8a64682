"""Sampled anatomies: reproducible, valid, with correct node sets, long axis and AHA segments."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from shared.errors import ConfigError, MeshError
from shared.mesh import Mesh
from simgen.meshes.aha import aha_segments
from simgen.meshes.anatomy import Anatomy, sample_anatomies, sample_shapes, sampling_intervals
from simgen.meshes.catalog import get_mesh
from simgen.meshes.shapes import SHAPES, LVShape, parameter_ranges
from simgen.meshes.topology import boundary_faces, signed_volumes
from simgen.meshes.validate import validate_mesh

NODES = {"lv": 400, "biv": 500}
COUNT = 8


def digest(mesh: Mesh) -> str:
    """SHA-256 of the points, cells, node sets and long axis."""
    h = hashlib.sha256()
    h.update(mesh.points.tobytes())
    h.update(mesh.cells.tobytes())
    for name in sorted(mesh.node_sets):
        h.update(name.encode())
        h.update(mesh.node_sets[name].tobytes())
    for name in ("apex", "base", "reference"):
        h.update(np.asarray(getattr(mesh.axis, name), float).tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module", params=["lv", "biv"])
def anatomies(request) -> tuple[str, list[Anatomy]]:
    return request.param, sample_anatomies(request.param, COUNT, seed=11, nodes=NODES[request.param])


# Digests of the default meshes before shape parameters existed: stores built from them must not change.
@pytest.mark.parametrize(
    "source, expected",
    [
        ("lv", "a6f99974a7d0a6186348b8ec9de65a6407abe92d7e18b1f4f6c91746cc9f60e7"),
        ("biv", "d1eb1b3a95c88e26914b62dc6c6a6a08cf7782dbf9f66c3c633164de8d614e57"),
    ],
)
def test_default_meshes_are_unchanged(source, expected):
    assert digest(get_mesh(source, 2000)) == expected


def test_same_seed_same_meshes_bit_for_bit(anatomies):
    family, first = anatomies
    again = sample_anatomies(family, 3, seed=11, nodes=NODES[family])
    for a, b in zip(first, again):
        assert a.params == b.params
        assert digest(a.mesh) == digest(b.mesh)
    other = sample_anatomies(family, 1, seed=12, nodes=NODES[family])[0]
    assert other.params != first[0].params and other.mesh.n_nodes > 0


def test_sample_does_not_depend_on_count_and_fixed_leaves_the_rest():
    five = sample_shapes("biv", 5, seed=3)
    assert sample_shapes("biv", 2, seed=3) == five[:2]
    fixed = sample_shapes("biv", 5, seed=3, fixed={"wall_thickness": 9.0, "bump_amplitude": 0})
    for free, pinned in zip(five, fixed):
        assert pinned.wall_thickness == 9.0 and pinned.bump_amplitude == 0.0
        assert {**free.params(), "wall_thickness": 9.0, "bump_amplitude": 0.0} == pinned.params()


@pytest.mark.parametrize("family", ["lv", "biv"])
def test_samples_spread_over_the_sampling_intervals(family):
    shapes = sample_shapes(family, 40, seed=0)
    for name, r in parameter_ranges(type(shapes[0])).items():
        lo, hi = r.draw
        assert r.lo <= lo < hi <= r.hi, name
        values = np.array([getattr(s, name) for s in shapes])
        assert lo <= values.min() < lo + 0.25 * (hi - lo), name
        assert hi - 0.25 * (hi - lo) < values.max() <= hi, name
    assert len({s.bump_seed for s in shapes}) == 40


def test_shape_ranges_replace_the_default_intervals_only():
    default = sample_shapes("biv", 20, seed=4)
    dilated = sample_shapes("biv", 20, seed=4, ranges={"rv_width": (30.0, 36.0), "rv_wrap_angle": [195, 200]})
    for a, b in zip(default, dilated):
        assert 30.0 <= b.rv_width <= 36.0 and 195.0 <= b.rv_wrap_angle <= 200.0
        assert {**a.params(), "rv_width": b.rv_width, "rv_wrap_angle": b.rv_wrap_angle} == b.params()
    assert sampling_intervals("biv")["rv_width"] == (14.0, 28.0)  # the admissible range goes to 36
    assert sampling_intervals("lv", {"length": (80, 90)})["length"] == (80.0, 90.0)


def _extreme_shapes(family: str) -> list[tuple[str, LVShape]]:
    """Each ranged parameter at each end of its admissible range, the others at their defaults;
    then 4 shapes with every parameter at an end (ends drawn at random) and the largest apex shift and bumps."""
    cls = SHAPES[family]
    ranges = parameter_ranges(cls)
    shapes = [(f"{name}={value:g}", cls(**{name: value})) for name, r in ranges.items() for value in (r.lo, r.hi)]
    rng = np.random.default_rng(0)
    for i in range(4):
        ends = {name: (r.lo, r.hi)[rng.integers(2)] for name, r in ranges.items()}
        ends.update(apex_offset=ranges["apex_offset"].hi, bump_amplitude=ranges["bump_amplitude"].hi, bump_seed=i)
        shapes.append((f"corner {i}", cls(**ends)))
    return shapes


@pytest.mark.parametrize("family", ["lv", "biv"])
def test_every_parameter_at_both_ends_of_its_range_gives_a_valid_mesh(family):
    for label, shape in _extreme_shapes(family):
        mesh = get_mesh(family, NODES[family], shape_params=shape.params())
        assert validate_mesh(mesh) is mesh, label
        assert (signed_volumes(mesh.points, mesh.cells) > 0).all(), label
        assert (np.bincount(aha_segments(mesh), minlength=18)[1:] > 0).all(), label


def test_bad_requests_are_refused():
    with pytest.raises(MeshError, match="procedural source"):
        sample_shapes("rv", 2, seed=0)
    with pytest.raises(MeshError, match="wall_thickness = 20.0 mm is outside"):
        sample_shapes("lv", 2, seed=0, fixed={"wall_thickness": 20.0})
    with pytest.raises(ConfigError, match="unknown key"):
        sample_shapes("lv", 2, seed=0, fixed={"thickness": 9.0})


def test_every_sample_is_valid(anatomies):
    family, samples = anatomies
    for a in samples:
        assert validate_mesh(a.mesh) is a.mesh
        assert (signed_volumes(a.mesh.points, a.mesh.cells) > 0).all()
        assert abs(a.mesh.n_nodes / NODES[family] - 1) < 0.06, a.mesh.name


def test_node_sets(anatomies):
    family, samples = anatomies
    for a in samples:
        sets = {key: set(idx.tolist()) for key, idx in a.mesh.node_sets.items()}
        assert sets["surface"] == set(np.unique(boundary_faces(a.mesh.cells)).tolist())
        assert sets["epicardium"] | sets["endocardium"] | sets["base"] == sets["surface"]
        assert not sets["epicardium"] & sets["endocardium"]
        if family == "biv":
            assert sets["endocardium"] == sets["lv_endocardium"] | sets["rv_endocardium"]
            assert sets["lv_endocardium"] and sets["rv_endocardium"]
        base = a.mesh.points[a.mesh.node_sets["base"], 2]
        np.testing.assert_allclose(base, a.params["base_height"], rtol=1e-12)
        assert a.mesh.points[:, 2].max() <= a.params["base_height"] + 1e-9


def test_long_axis_runs_from_apex_to_base(anatomies):
    _, samples = anatomies
    for a in samples:
        axis, p = a.mesh.axis, a.params
        angle = np.radians(p["apex_offset_angle"])
        epi_long = p["length"] - p["base_height"]
        apex = [p["apex_offset"] * np.cos(angle), p["apex_offset"] * np.sin(angle), -epi_long]
        np.testing.assert_allclose(axis.apex, apex, atol=1e-9)
        np.testing.assert_allclose(axis.base, [0, 0, p["base_height"]])
        assert axis.length == pytest.approx(np.hypot(p["length"], p["apex_offset"]))
        assert abs(axis.reference @ axis.direction) < 1e-12 and np.linalg.norm(axis.reference) == pytest.approx(1)
        # The lowest node is next to the apex: the axis apex is the tip of the mesh.
        tip = a.mesh.points[np.argmin(a.mesh.points[:, 2])]
        assert tip[2] >= -epi_long - 1e-9
        assert np.linalg.norm(tip - axis.apex) < 0.2 * p["length"]


def test_all_aha_segments_are_populated(anatomies):
    _, samples = anatomies
    for a in samples:
        counts = np.bincount(aha_segments(a.mesh), minlength=18)[1:]
        assert (counts > 0).all(), (a.mesh.name, counts)


def test_bumps_keep_heights_and_wall_thickness():
    params = sample_shapes("lv", 1, seed=5, fixed={"bump_amplitude": 3.0, "apex_offset": 0.0})[0].params()
    smooth = get_mesh("lv", 600, shape_params={**params, "bump_amplitude": 0.0})
    bumpy = get_mesh("lv", 600, shape_params=params)
    np.testing.assert_array_equal(smooth.cells, bumpy.cells)
    np.testing.assert_array_equal(smooth.points[:, 2], bumpy.points[:, 2])
    moved = np.linalg.norm(bumpy.points - smooth.points, axis=1)
    assert moved.max() > 2.0  # a few mm, not a no-op
    # Endocardial node i and epicardial node i are the ends of one transmural column.
    thickness = [
        np.linalg.norm(m.points[m.node_sets["epicardium"]] - m.points[m.node_sets["endocardium"]], axis=1)
        for m in (smooth, bumpy)
    ]
    np.testing.assert_allclose(thickness[1], thickness[0], rtol=1e-12)


def test_triangle_kind():
    surface = sample_anatomies("biv", 1, seed=2, nodes=600, kind="triangle")[0].mesh
    assert surface.cell_type == "triangle" and validate_mesh(surface) is surface
    assert surface.name == "biv-000"
