"""Fibres in build specs and stores: rule and angles per mesh, anisotropy in [solver] or per tissue setting,
the fibres kept in the store, verified, repaired; isotropic specs keep their meaning and hash."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
import zarr

from shared.errors import ConfigError, TissueError
from shared.reader import read_activation, read_mesh, subject_attrs
from shared.tissue import TissueSpec
from simgen.meshes.fibres import ldrb_fibres, ldrb_frames
from simgen.store.manifest import entry_mesh
from simgen.store.repair import repair_store
from simgen.store.runner import build
from simgen.store.spec import FibreRule, spec_hash
from simgen.store.verify import verify_store


def fibre_spec(tiny_spec, **patch):
    """:func:`tiny_spec` on a 400-node LV with LDRB fibres at +50/-50, D_l / D_t = 4, and an isotropic setting."""
    mesh = {"id": "lv", "source": "lv", "nodes": 400, "fibres": {"rule": "ldrb", "helix_endo": 50, "helix_epi": -50}}
    iso = {"name": "iso", "anisotropy": 1.0}
    return tiny_spec(
        meshes=[mesh], tissue=["healthy"], custom_tissue=[iso], solver={"frames": 8, "anisotropy": 4.0}, **patch
    )


@pytest.fixture(scope="module")
def fibre_store(tmp_path_factory, tiny_spec):
    store = tmp_path_factory.mktemp("fibres") / "fibres.zarr"
    build(fibre_spec(tiny_spec), store, workers=2)
    return store


def test_the_store_keeps_the_rule_fibres_and_each_subject_its_anisotropy(fibre_store, tiny_spec):
    spec = fibre_spec(tiny_spec)
    stored = read_mesh(fibre_store, "lv")
    rule = ldrb_fibres(entry_mesh(spec.meshes[0]), 50.0, -50.0)[0]
    assert np.array_equal(stored.fibres, rule.astype(np.float32).astype(np.float64))
    assert subject_attrs(fibre_store, "lv-healthy")["solver"]["anisotropy"] == 4.0
    assert "anisotropy" not in subject_attrs(fibre_store, "lv-iso")["solver"]
    aniso, iso = read_activation(fibre_store, "lv-healthy"), read_activation(fibre_store, "lv-iso")
    assert np.nanmax(np.abs(aniso - iso)) > 0.5  # along and across the fibres conduct apart
    report = verify_store(fibre_store, sample=2)
    assert not report.problems and report.chunks_recomputed == 4


def test_a_lost_fibre_array_is_repaired_to_the_same_bytes(fibre_store, tmp_path, store_bytes):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(fibre_store, copy)
    before = store_bytes(copy)
    shutil.rmtree(copy / "meshes" / "lv" / "fibre")
    assert not verify_store(copy, sample=0).ok, "the loss is found"
    report = repair_store(copy, workers=1)
    assert report.build.simulations == 0 and store_bytes(copy) == before


def test_fibre_and_anisotropy_settings_are_checked(tiny_spec, reference_store):
    with pytest.raises(ConfigError, match=r"meshes \['lv'\] have none"):
        tiny_spec(solver={"anisotropy": 4.0})
    with pytest.raises(ConfigError, match=r"meshes \['lv'\] have none"):
        tiny_spec(custom_tissue=[{"name": "fast", "anisotropy": 2.0}])
    with pytest.raises(ConfigError, match="fibres need a volume mesh"):
        tiny_spec(meshes=[{"id": "lv", "source": "lv", "kind": "triangle", "fibres": {}}])
    with pytest.raises(ConfigError, match="fibre rule 'file' needs a mesh file"):
        tiny_spec(meshes=[{"id": "lv", "source": "lv", "fibres": {"rule": "file"}}])
    with pytest.raises(ConfigError, match=r"helix_endo = 120 must be an angle in \[-90, 90\]"):
        FibreRule(helix_endo=120)
    with pytest.raises(TissueError, match="anisotropy must be a ratio"):
        TissueSpec("x", anisotropy=0.5)
    plain = tiny_spec()
    assert spec_hash(plain) == spec_hash(tiny_spec(meshes=[{"id": "lv", "source": "lv", "nodes": 500}]))
    assert "fibre" not in zarr.open_group(str(reference_store), path="meshes/lv").array_keys()


def test_sheets_are_stored_with_ldrb_fibres_and_builds_conduct_along_them(tiny_spec, tmp_path):
    """With [solver] sheet_anisotropy the store keeps the rule's sheets beside its fibres, and verify
    recomputes the orthotropic simulations bit for bit."""
    spec = tiny_spec(
        meshes=[{"id": "lv", "source": "lv", "nodes": 400, "fibres": {"sheet_endo": -60, "sheet_epi": 30}}],
        tissue=["healthy"],
        solver={"frames": 8, "anisotropy": 4.0, "sheet_anisotropy": 2.0},
    )
    store = tmp_path / "sheets.zarr"
    build(spec, store, workers=1)
    stored = read_mesh(store, "lv")
    frames = ldrb_frames(entry_mesh(replace(spec.meshes[0], fibres=None)), 60.0, -60.0, -60.0, 30.0)
    assert np.array_equal(stored.sheets, frames.sheets.astype(np.float32).astype(np.float64))
    assert verify_store(store, sample=2).ok
    with pytest.raises(ConfigError, match=r"meshes \['lv'\] have none"):
        tiny_spec(solver={"sheet_anisotropy": 2.0})
