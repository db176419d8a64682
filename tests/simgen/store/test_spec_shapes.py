"""Random anatomies in build specs: expansion of ``shape = "random"`` mesh tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.errors import ConfigError, MeshError
from simgen.meshes.anatomy import sample_shapes
from simgen.meshes.catalog import get_mesh
from simgen.store import MeshEntry, load_spec, spec_from_mapping, spec_hash, spec_to_dict
from simgen.store.manifest import make_plan

SPECS = Path(__file__).resolve().parents[3] / "specs"

RANDOM_BIV = {
    "id": "biv",
    "source": "biv",
    "nodes": 600,
    "shape": "random",
    "count": 3,
    "seed": 3,
    "shape_params": {"wall_thickness": 9.0},
}


def spec(*meshes: dict, **extra):
    return spec_from_mapping({"meshes": list(meshes), "tissue": ["healthy"], **extra})


def test_random_table_expands_into_numbered_anatomies():
    meshes = spec(RANDOM_BIV).meshes
    assert [m.id for m in meshes] == ["biv-000", "biv-001", "biv-002"]
    assert all((m.source, m.nodes, m.kind) == ("biv", 600, "tetra") for m in meshes)
    expected = sample_shapes("biv", 3, seed=3, fixed={"wall_thickness": 9.0})
    assert [m.shape_params for m in meshes] == [s.params() for s in expected]
    assert all(m.shape_params["wall_thickness"] == 9.0 for m in meshes)
    assert len({m.shape_params["length"] for m in meshes}) == 3


def test_expanded_spec_round_trips_with_the_same_hash():
    first = spec(RANDOM_BIV, {"id": "lv", "source": "lv", "nodes": 500})
    again = spec_from_mapping(spec_to_dict(first))
    assert again == first and spec_hash(again) == spec_hash(first)
    assert spec_hash(spec(RANDOM_BIV, {"id": "lv", "source": "lv", "nodes": 500})) == spec_hash(first)
    assert spec_hash(spec({**RANDOM_BIV, "seed": 4})) != spec_hash(spec(RANDOM_BIV))


def test_plain_specs_keep_their_meaning_and_record():
    for name in ("default.toml", "demo.toml"):
        for entry in spec_to_dict(load_spec(SPECS / name))["meshes"]:
            assert set(entry) == {"id", "source", "nodes", "kind"}  # the hash of old specs is unchanged
    assert spec({"id": "lv", "shape": "default"}).meshes == (MeshEntry("lv"),)


def test_shipped_anatomy_spec_keeps_its_hash():
    # Stores built from specs/anatomies.toml record this hash: its draws must not change.
    assert spec_hash(load_spec(SPECS / "anatomies.toml")) == (
        "9ed1970c7b160df01056d2c81be0e1b0be1addce77b45105c97ceb3034210396"
    )


def test_dilated_rv_spec_adds_to_the_anatomies_of_the_shipped_one():
    base, dilated = load_spec(SPECS / "anatomies.toml"), load_spec(SPECS / "anatomies-rv.toml")
    assert dilated.meshes[: len(base.meshes)] == base.meshes  # the same hearts, so the same split
    extra = dilated.meshes[len(base.meshes) :]
    assert [m.id for m in extra] == [f"bivd-{i:03d}" for i in range(16)]
    for m in extra:
        p = m.shape_params
        assert 24 <= p["rv_width"] <= 36 and 170 <= p["rv_wrap_angle"] <= 200 and 0.8 <= p["rv_length"] <= 0.9
    assert sum(m.shape_params["rv_width"] > 28 for m in extra) >= 8  # beyond the default sampling interval


def test_shape_ranges_set_the_sampling_intervals():
    table = {**RANDOM_BIV, "count": 6, "shape_ranges": {"rv_width": [30.0, 36.0], "length": [70, 70]}}
    meshes = spec(table).meshes
    assert all(30.0 <= m.shape_params["rv_width"] <= 36.0 for m in meshes)
    assert all(m.shape_params["length"] == 70.0 for m in meshes)
    expected = sample_shapes("biv", 6, seed=3, fixed={"wall_thickness": 9.0}, ranges=table["shape_ranges"])
    assert [m.shape_params for m in meshes] == [s.params() for s in expected]
    # The record holds the drawn parameters only: it reads back to the same spec.
    assert spec_from_mapping(spec_to_dict(spec(table))) == spec(table)


def test_fixed_shape_without_random_is_completed():
    (entry,) = spec({"id": "lv", "source": "lv", "shape_params": {"length": 90}}).meshes
    assert entry.shape_params["length"] == 90.0 and entry.shape_params["wall_thickness"] == 10.0


@pytest.mark.parametrize(
    "table, error, match",
    [
        ({"count": 2}, ConfigError, "count, seed and shape_ranges apply to shape = 'random' only"),
        ({"shape_ranges": {}}, ConfigError, "count, seed and shape_ranges apply to shape = 'random' only"),
        ({"shape": "random", "shape_ranges": [1, 2]}, ConfigError, "shape_ranges must be a table"),
        (
            {"shape": "random", "shape_ranges": {"length": [60.0, 80.0]}},
            MeshError,
            r"mesh 'x': shape_ranges: length = \[60, 80\] must satisfy lo <= hi within the admissible "
            r"range 70\.\.100 mm",
        ),
        ({"shape": "random", "shape_ranges": {"length": [90.0, 80.0]}}, MeshError, "must satisfy lo <= hi"),
        ({"shape": "random", "shape_ranges": {"length": [float("nan"), 80.0]}}, MeshError, "must satisfy lo <= hi"),
        ({"shape": "random", "shape_ranges": {"rv_width": [20, 30]}}, ConfigError, "unknown parameter"),
        ({"shape": "random", "shape_ranges": {"length": 80.0}}, ConfigError, r"length must be \[lo, hi\]"),
        ({"shape": "ellipsoid"}, ConfigError, r"shape 'ellipsoid' is not one of \['default', 'random'\]"),
        ({"shape": "random", "source": "heart.vtu"}, ConfigError, "needs source 'lv' or 'biv'"),
        ({"shape": "random", "count": 0}, ConfigError, "count must be an integer >= 1"),
        ({"shape": "random", "count": 1001}, ConfigError, "count must be at most 1000"),
        ({"shape": "random", "seed": -1}, ConfigError, "seed must be an integer >= 0"),
        (
            {"shape": "random", "shape_params": {"wall_thickness": 20.0}},
            MeshError,
            r"mesh 'x': LV shape: wall_thickness = 20.0 mm is outside the physiological range 7\.\.14 mm",
        ),
        ({"shape": "random", "shape_params": {"rv_width": 20.0}}, ConfigError, r"unknown key\(s\) \['rv_width'\]"),
        ({"shape_params": {"length": 200.0}}, MeshError, "mesh 'x': LV shape: length = 200.0 mm"),
        ({"source": "heart.vtu", "shape_params": {}}, MeshError, "procedural source"),
    ],
)
def test_bad_tables_are_refused(table, error, match):
    with pytest.raises(error, match=match):
        spec({"id": "x", **table})


def test_expanded_ids_must_stay_unique():
    with pytest.raises(ConfigError, match=r"duplicate mesh ids \['biv-001'\]"):
        spec(RANDOM_BIV, {"id": "biv-001", "source": "lv"})


def test_plan_builds_the_sampled_anatomies():
    table = {"id": "lv", "source": "lv", "nodes": 300, "shape": "random", "count": 2, "seed": 1}
    plan = make_plan(spec(table, sites={"count": 3}, output={"sock_electrodes": 0}))
    for entry in plan.spec.meshes:
        mesh = plan.meshes[entry.id]
        expected = get_mesh("lv", 300, shape_params=entry.shape_params)
        np.testing.assert_array_equal(mesh.points, expected.points)
    assert not np.array_equal(plan.meshes["lv-000"].points[:10], plan.meshes["lv-001"].points[:10])
