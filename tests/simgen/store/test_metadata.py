"""The self-describing store: CF attributes, xarray coordinates, provenance, resolved solver settings, statistics."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr
import zarr

from shared.errors import ConfigError
from shared.reader import read_statistics
from shared.schema import MESH_ARRAYS, SCHEMA_VERSION, SUBJECT_ARRAYS, array_attributes
from shared.split import canonical_part
from shared.units import MS_PER_TIME_UNIT
from simgen.solver.simulate import Simulator
from simgen.store import make_plan
from simgen.store.layout import read_mesh, read_tissue
from simgen.store.metadata import provenance


def _open(store, group: str) -> xr.Dataset:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zarr's note that consolidated metadata is not in the v3 spec yet
        return xr.open_zarr(store, group=group)


def test_xarray_shows_labelled_coordinates_with_units(reference_store, tiny_spec):
    ds = _open(reference_store, "subjects/lv-scar-apex")
    assert {"site", "times", "time_ms", "x", "y", "z"} <= set(ds.coords)
    assert ds["u"].dims == ("site", "time", "node")
    assert set(ds["u"].coords) == {"site", "times", "time_ms", "x", "y", "z"}
    assert set(ds["activation"].coords) == {"site", "x", "y", "z"}
    mesh = read_mesh(reference_store, "lv")
    stim = zarr.open_group(str(reference_store), mode="r")["meshes/lv/stim_nodes"][...]
    assert np.array_equal(ds["site"].values, stim) and ds.indexes["site"].tolist() == stim.tolist()
    solver = tiny_spec().solver
    times = solver.output_interval * np.arange(1, solver.frames + 1)
    assert np.allclose(ds["times"].values, times) and np.allclose(ds["time_ms"].values, times * MS_PER_TIME_UNIT)
    assert np.array_equal(np.stack([ds[a].values for a in "xyz"], axis=1), mesh.points)
    expected = {
        "u": ("1", "transmembrane potential"),
        "activation": ("12.9 ms", "activation time"),
        "times": ("12.9 ms", "frame time"),
        "time_ms": ("ms", "frame time"),
        "x": ("mm", "node x coordinate"),
        "site": ("1", "stimulated node id"),
    }
    for name, (units, long_name) in expected.items():
        assert ds[name].attrs["units"] == units and ds[name].attrs["long_name"].startswith(long_name), name
    assert ds["times"].dtype == np.float64  # model time units, not decoded as a timedelta


def test_every_array_carries_its_schema_attributes(reference_store):
    root = zarr.open_group(str(reference_store), mode="r")
    for name in SUBJECT_ARRAYS:
        attrs = dict(root[f"subjects/lv-healthy/{name}"].attrs)
        assert attrs == array_attributes(SUBJECT_ARRAYS, name) and attrs["units"] and attrs["long_name"], name
    for name in MESH_ARRAYS:
        assert dict(root[f"meshes/lv/{name}"].attrs) == array_attributes(MESH_ARRAYS, name), name
    assert array_attributes(SUBJECT_ARRAYS, "u")["coordinates"] == "times time_ms x y z"
    assert "coordinates" not in array_attributes(SUBJECT_ARRAYS, "done")


def test_root_and_subject_attributes_record_model_solver_and_provenance(reference_store, tiny_spec):
    root = zarr.open_group(str(reference_store), mode="r")
    prov = root.attrs["provenance"]
    assert prov["software"] == "metapns" and prov["version"] == "0.1.0"
    assert prov["created"] == "2024-01-01T00:00:00+00:00"  # SOURCE_DATE_EPOCH of the build tests
    assert prov["git_commit"] is None or len(prov["git_commit"]) == 40
    sim = root.attrs["simulation"]
    assert sim["constants"] == {
        "variant": "standard",
        "k": 8.0,
        "eps0": 0.002,
        "mu1": 0.2,
        "mu2": 0.3,
        "eps_simple": 0.01,
    }
    assert (sim["stimulus_duration"], sim["frames"], sim["units"]["time"]) == (1.0, 8, "12.9 ms")
    assert "du/dt" in sim["equations"][0]
    assert root.attrs["split"]["fractions"] == {"train": 0.7, "validation": 0.1, "test": 0.2}
    assert "8 frames" in root.attrs["summary"] and f"schema version {SCHEMA_VERSION}" in root.attrs["summary"]
    plan = make_plan(tiny_spec())
    for subject in plan.subjects:
        g = root[f"subjects/{subject.id}"]
        sim = Simulator(read_mesh(reference_store, "lv"), read_tissue(reference_store, subject.id), plan.spec.solver)
        assert g.attrs["solver"] == {
            "integrator": sim.integrator,
            "dt": sim.dt,
            "steps_per_frame": sim.steps_per_frame,
            "stimulus_radius": sim.stimulus_radius,
            "stimulus_region": "ball",
            "stimulus_duration": 1.0,
        }
        assert g.attrs["split"] == canonical_part(subject.id)


def test_provenance_date_is_now_unless_source_date_epoch(monkeypatch):
    monkeypatch.delenv("SOURCE_DATE_EPOCH")
    created = np.datetime64(provenance()["created"][:19])
    assert abs(created - np.datetime64("now")) < np.timedelta64(60, "s")
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")
    assert provenance()["created"] == "1970-01-01T00:00:00+00:00"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(ConfigError, match="SOURCE_DATE_EPOCH"):
        provenance()


def _described(values: np.ndarray) -> dict:
    finite = values[np.isfinite(values)].astype(np.float64)
    return {"count": finite.size, "mean": finite.mean(), "std": finite.std(), "min": finite.min(), "max": finite.max()}


def _close(stats: dict, expected: dict) -> bool:
    return stats["count"] == expected["count"] and all(
        np.isclose(stats[k], expected[k], rtol=1e-12, atol=1e-12) for k in ("mean", "std", "min", "max")
    )


def test_statistics_describe_the_data(reference_store):
    root = zarr.open_group(str(reference_store), mode="r")
    data = {name: [] for name in ("u", "activation")}
    for subject_id in ("lv-healthy", "lv-scar-apex"):
        stats = read_statistics(reference_store, subject_id)
        for name in data:
            values = root[f"subjects/{subject_id}/{name}"][...]
            data[name].append(values.ravel())
            assert _close(stats[name], _described(values)), (subject_id, name)
    stats = read_statistics(reference_store)
    assert all(_close(stats[name], _described(np.concatenate(data[name]))) for name in data)


def test_subjects_simulate_with_the_stimulus_they_recorded_whatever_the_defaults(tmp_path):
    """Stores built before the stimulus was in mm record no region (edge-path patches) and, in version 1,
    no radius either (1.5 mean edge lengths): a resume, a repair and verify simulate with those."""
    from dataclasses import replace

    from simgen.meshes.ellipsoid import lv_ellipsoid
    from simgen.solver.simulate import SolverConfig
    from simgen.store.metadata import recorded_solver

    mesh = lv_ellipsoid(500, "tetra")
    root = zarr.open_group(tmp_path / "old.zarr", mode="w")
    root.attrs["spec"] = {"solver": {"frames": 4}}
    group = root.create_group("subjects/lv-healthy")

    def recorded(solver: dict) -> SolverConfig:
        group.attrs["solver"] = solver
        return recorded_solver(str(tmp_path / "old.zarr"), "lv-healthy", SolverConfig(frames=4), mesh)

    old = recorded({"dt": 0.02, "steps_per_frame": 30, "stimulus_radius": 8.1})
    assert (old.integrator, old.stimulus_radius, old.region) == ("euler", 8.1, "geodesic")
    oldest = recorded({"dt": 0.02, "steps_per_frame": 30})
    assert oldest.stimulus_radius == pytest.approx(1.5 * mesh.mean_edge_length()) and oldest.region == "geodesic"
    spec_radius = recorded_solver(str(tmp_path / "old.zarr"), "lv-healthy", SolverConfig(stimulus_radius=6.0), mesh)
    assert spec_radius.stimulus_radius == 6.0  # a spec that set the radius ran it
    new = recorded({"integrator": "imex", "stimulus_radius": 10.0, "stimulus_region": "ball", "dt": 0.05})
    assert new == replace(SolverConfig(frames=4), integrator="imex", stimulus_radius=10.0, stimulus_region="ball")


def test_verify_recomputes_with_the_recorded_stimulus(tmp_path, reference_store):
    """A subject whose record is changed to another patch no longer verifies: verify reads the record."""
    import shutil

    from simgen.store.verify import verify_store

    store = tmp_path / "copy.zarr"
    shutil.copytree(reference_store, store)
    group = zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")
    solver = dict(group.attrs["solver"])
    del solver["stimulus_region"]  # as a store built before the ball: edge-path patches
    group.attrs["solver"] = solver
    report = verify_store(str(store), sample=100)
    assert report.chunks_recomputed and report.problems
    assert all("lv-healthy" in str(p) and "recomputation" in str(p) for p in report.problems), report.problems


def test_builds_record_which_simulations_start_a_wave_and_status_and_card_count_them(reference_store):
    from typer.testing import CliRunner

    from shared.capture import activated_fraction, started_wave
    from simgen.cli import app
    from simgen.store.card import dataset_card
    from simgen.store.inspect import store_status

    root = zarr.open_group(str(reference_store), mode="r")
    total = 0
    for row in store_status(reference_store):
        group = root[f"subjects/{row.subject_id}"]
        recorded = group.attrs["capture"]["activated_fraction"]
        np.testing.assert_allclose(recorded, activated_fraction(group["activation"][...]), atol=1e-4)
        assert row.no_wave == int((~started_wave(recorded)).sum())
        total += row.no_wave
    sites = sum(r.sites for r in store_status(reference_store))
    assert f"| simulations that start no wave (stimulus in a scar core) | {total} of {sites} " in dataset_card(
        reference_store
    )
    assert root.attrs["simulation"]["scar_border"] == "boundary"
    result = CliRunner().invoke(app, ["status", str(reference_store)], terminal_width=200)
    assert f"{total} of {sites} simulations start no propagating wave" in " ".join(result.output.split())
