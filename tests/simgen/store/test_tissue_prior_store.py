"""A build spec's ``[tissue_prior]``: expanded into drawn ``custom_tissue`` settings (and the spec's hash), built
into a store whose subjects record each draw's tissue and action-potential scale, and verified."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import zarr

from shared.errors import ConfigError
from shared.reader import read_mesh, read_sites, read_tissue, read_u, subject_attrs
from shared.tissue import TissueSpec
from simgen.solver.simulate import Simulator
from simgen.store.metadata import recorded_solver
from simgen.store.spec import load_spec, spec_from_mapping, spec_hash, spec_to_dict
from simgen.store.verify import verify_store
from simgen.tissue import tissue_spec_from_mapping
from simgen.tissue.fields import tissue_fields
from simgen.tissue.prior import TissuePrior, draw_tissues

SPECS = Path(__file__).resolve().parents[3] / "specs"

#: spec_hash of specs/demo.toml, computed at the commit before the tissue prior (cea66c5~1).
DEMO_HASH = "3b21bbe86055bc41bd040633e5047946afb6817e7ff516c5cdfe7c1485dc03c0"

PRIOR_TOML = """\
name = "prior-test"
seed = 0

[[meshes]]
id = "lv"
source = "lv"
nodes = 700

[tissue_prior]
count = 3
seed = {seed}
a = [0.13, 0.17]
D = [0.6, 1.8]
apd_scale = [0.7, 1.4]
scars = [1, 2]
radius = [8.0, 12.0]
border_width = [2.0, 4.0]
fibrosis = 1.0
fibrosis_density = [0.1, 0.2]
fibrosis_patch = [4.0, 6.0]

[sites]
count = 3

[solver]
frames = 12

[output]
chunk_sites = 2
sock_electrodes = 20
"""

#: Fields of the tissue prior that a spec without one must not write (a new key would change every old hash).
NEW_FIELDS = {"tissue_prior", "apd_scale", "fibrosis", "ventricle", "height", "angle", "elongation", "transmural"}


def _write(tmp_path: Path, seed: int = 5, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(PRIOR_TOML.format(seed=seed))
    return path


def _keys(value) -> set[str]:
    """Every key anywhere in a nested mapping."""
    if isinstance(value, dict):
        return set(value) | {k for v in value.values() for k in _keys(v)}
    if isinstance(value, list):
        return {k for v in value for k in _keys(v)}
    return set()


def _none_valued(value) -> set[str]:
    if isinstance(value, dict):
        return {k for k, v in value.items() if v is None} | {k for v in value.values() for k in _none_valued(v)}
    if isinstance(value, list):
        return {k for v in value for k in _none_valued(v)}
    return set()


def test_a_spec_without_a_prior_keeps_its_hash() -> None:
    spec = load_spec(SPECS / "demo.toml")
    data = spec_to_dict(spec)
    assert not _keys(data) & NEW_FIELDS
    assert not _none_valued(data)
    assert spec_hash(spec) == DEMO_HASH


def test_default_tissue_writes_none_of_the_new_fields() -> None:
    data = spec_to_dict(spec_from_mapping({}))
    assert len(data["custom_tissue"]) == 0 and not _keys(data) & NEW_FIELDS and not _none_valued(data)


def test_the_prior_expands_into_custom_tissue(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path))
    data = spec_to_dict(spec)
    assert "tissue_prior" not in data and data["tissue"] == []
    assert [t["name"] for t in data["custom_tissue"]] == ["draw-000", "draw-001", "draw-002"]
    assert [t.name for t in spec.settings()] == ["draw-000", "draw-001", "draw-002"]
    prior = TissuePrior(
        count=3,
        seed=5,
        a=(0.13, 0.17),
        D=(0.6, 1.8),
        apd_scale=(0.7, 1.4),
        scars=(1, 2),
        radius=(8.0, 12.0),
        border_width=(2.0, 4.0),
        fibrosis=1.0,
        fibrosis_density=(0.1, 0.2),
        fibrosis_patch=(4.0, 6.0),
    )
    assert list(spec.settings()) == draw_tissues(prior, spec.solver)
    for t in spec.settings():
        assert t.fibrosis is not None and t.apd_scale is not None and 1 <= len(t.scars) <= 2


def test_the_expanded_spec_round_trips(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path))
    again = spec_from_mapping(json.loads(json.dumps(spec_to_dict(spec))))
    assert again == spec and spec_hash(again) == spec_hash(spec)


def test_the_hash_follows_the_prior_seed(tmp_path: Path) -> None:
    five, again = load_spec(_write(tmp_path, 5, "a.toml")), load_spec(_write(tmp_path, 5, "b.toml"))
    six = load_spec(_write(tmp_path, 6, "c.toml"))
    assert spec_hash(five) == spec_hash(again)
    assert spec_hash(five) != spec_hash(six)
    assert list(five.settings()) != list(six.settings())


def test_named_settings_and_given_custom_tissue_come_first() -> None:
    spec = spec_from_mapping(
        {
            "tissue": ["healthy"],
            "custom_tissue": [{"name": "mine", "healthy": {"a": 0.14}}],
            "tissue_prior": {"count": 2, "scars": [0, 0], "name": "p"},
        }
    )
    assert [t.name for t in spec.settings()] == ["healthy", "mine", "p-000", "p-001"]


@pytest.mark.parametrize(
    "prior, match",
    [
        ({"count": 0}, "count"),
        ({"D": [1.0, 0.5]}, "D must be"),
        ({"bogus": 1}, "bogus"),
        ({"D": [0.5, 1.0], "cv": [0.5, 1.0]}, "not both"),
    ],
)
def test_a_bad_prior_in_a_spec_names_its_key(prior: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        spec_from_mapping({"tissue_prior": prior})


@pytest.fixture(scope="module")
def prior_store(tmp_path_factory) -> tuple[Path, object]:
    from simgen.store.runner import build

    folder = tmp_path_factory.mktemp("prior")
    spec = load_spec(_write(folder))
    store = folder / "prior.zarr"
    build(spec, store, workers=2)
    return store, spec


def test_store_subjects_are_the_draws(prior_store) -> None:
    store, spec = prior_store
    root = zarr.open_group(str(store), mode="r")
    assert sorted(root["subjects"].group_keys()) == ["lv-draw-000", "lv-draw-001", "lv-draw-002"]
    assert root.attrs["spec_hash"] == spec_hash(spec)


def test_subject_tissue_round_trips_into_the_stored_fields(prior_store) -> None:
    store, spec = prior_store
    mesh = read_mesh(store, "lv")
    labels = set()
    for tissue in spec.settings():
        subject = f"lv-{tissue.name}"
        recorded = tissue_spec_from_mapping(subject_attrs(store, subject)["tissue"])
        assert isinstance(recorded, TissueSpec) and recorded == tissue
        stored = read_tissue(store, subject)
        fields = tissue_fields(mesh, recorded)
        np.testing.assert_array_equal(stored.label, fields.label)
        np.testing.assert_allclose(stored.a, fields.a, rtol=1e-6)
        np.testing.assert_allclose(stored.D, fields.D, rtol=1e-6)
        labels |= set(np.unique(stored.label).tolist())
    assert labels == {0, 1, 2, 3}  # healthy, border, core and fibrosis are all in the store


def test_subject_solver_records_the_apd_scale(prior_store) -> None:
    store, spec = prior_store
    mesh = read_mesh(store, "lv")
    root_eps0 = zarr.open_group(str(store), mode="r").attrs["spec"]["solver"]["model"]["eps0"]
    assert root_eps0 == spec.solver.model.eps0
    for tissue in spec.settings():
        subject = f"lv-{tissue.name}"
        assert subject_attrs(store, subject)["solver"]["apd_scale"] == tissue.apd_scale
        model = recorded_solver(str(store), subject, spec.solver, mesh).model
        assert model.eps0 == pytest.approx(root_eps0 / tissue.apd_scale, rel=1e-12)
        assert model.mu1 == pytest.approx(spec.solver.model.mu1 / tissue.apd_scale, rel=1e-12)
        assert model.k == spec.solver.model.k


def test_stored_results_ran_with_the_scaled_model(prior_store) -> None:
    store, spec = prior_store
    mesh = read_mesh(store, "lv")
    tissue = spec.settings()[0]
    subject = f"lv-{tissue.name}"
    solver = recorded_solver(str(store), subject, spec.solver, mesh)
    sites = read_sites(store, "lv")[:2]
    stored = np.asarray(read_u(store, subject, [0, 1]))
    fields = read_tissue(store, subject)
    scaled = Simulator(mesh, fields, solver, backend="numba").run(sites).u
    np.testing.assert_array_equal(stored, scaled.astype(stored.dtype))
    unscaled = Simulator(mesh, fields, dataclasses.replace(solver, model=spec.solver.model), backend="numba")
    assert not np.array_equal(stored, unscaled.run(sites).u.astype(stored.dtype))


def test_the_store_verifies(prior_store) -> None:
    store, _ = prior_store
    report = verify_store(store, sample=2)
    assert report.ok, report.problems
    assert report.chunks_recomputed == 6


def test_several_priors_draw_under_their_own_names() -> None:
    """``[[tissue_prior]]`` tables: each draws its settings, named by its own prefix; one table is the same as the
    single ``[tissue_prior]`` of the same content."""
    slow = {"name": "slow", "count": 2, "seed": 1, "D": [0.3, 0.5], "scars": [0, 0]}
    scar = {"name": "scar", "count": 1, "seed": 2, "scars": [1, 1]}
    both = spec_to_dict(spec_from_mapping({"tissue_prior": [slow, scar]}))
    assert [t["name"] for t in both["custom_tissue"]] == ["slow-000", "slow-001", "scar-000"]
    assert all(0.3 <= t["healthy"]["D"] <= 0.5 for t in both["custom_tissue"][:2])
    assert spec_to_dict(spec_from_mapping({"tissue_prior": [slow]})) == spec_to_dict(
        spec_from_mapping({"tissue_prior": slow})
    )
    with pytest.raises(ConfigError, match="distinct names"):
        spec_from_mapping({"tissue_prior": [slow, slow]})
    with pytest.raises(ConfigError, match=r"tissue_prior\[1\]"):
        spec_from_mapping({"tissue_prior": [slow, {**scar, "colour": 1}]})
