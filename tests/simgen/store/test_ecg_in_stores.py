"""ECGs in stores (issue 56 item 2): each simulation's 12 leads stored beside u, self-described, verified and
repaired like every chunk; specs without ``[output] ecg`` keep their hash and layout."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from shared.ecg import ECG_ATTRS, ELECTRODES, LEADS, Electrodes, PseudoECG, leads
from shared.errors import ConfigError
from simgen.store.repair import repair_store
from simgen.store.runner import build
from simgen.store.spec import spec_hash
from simgen.store.verify import verify_store


@pytest.fixture(scope="module")
def ecg_store(tmp_path_factory, tiny_spec):
    store = tmp_path_factory.mktemp("ecg") / "ecg.zarr"
    build(tiny_spec(output={"chunk_sites": 3, "sock_electrodes": 40, "ecg": True}), store, workers=2)
    return store


def test_the_store_keeps_each_simulations_twelve_leads_with_their_electrodes(ecg_store):
    from shared.reader import read_mesh, read_tissue

    root = zarr.open_group(str(ecg_store), mode="r")
    mesh_group, subject = root["meshes/lv"], root["subjects/lv-scar-apex"]
    assert mesh_group.attrs["ecg"] == ECG_ATTRS and list(mesh_group.attrs["ecg"]["leads"]) == list(LEADS)
    ecg, u = subject["ecg"][...], subject["u"][...]
    assert ecg.shape == (6, 12, 8) and subject["ecg"].attrs["units"] == "mV"
    electrodes = Electrodes(ELECTRODES, mesh_group["ecg_electrodes"][...])
    operator = PseudoECG.assemble(read_mesh(ecg_store, "lv"), electrodes, read_tissue(ecg_store, "lv-scar-apex").D)
    np.testing.assert_allclose(ecg, leads(operator.potentials(u), electrodes), rtol=1e-5, atol=1e-6)
    report = verify_store(ecg_store, sample=2)
    assert report.ok and report.chunks_recomputed == 4


def test_a_lost_or_altered_ecg_chunk_is_found_and_computed_again(ecg_store, tmp_path, store_bytes):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(ecg_store, copy)
    before = store_bytes(copy)
    shards = sorted((copy / "subjects" / "lv-healthy" / "ecg" / "c").rglob("*"))
    next(p for p in shards if p.is_file()).unlink()
    report = verify_store(copy, sample=0)
    assert not report.ok and any("ecg" in p for p in report.problems)
    assert repair_store(copy, workers=1).build.simulations == 3 and store_bytes(copy) == before
    altered = zarr.open_group(str(copy), path="subjects/lv-healthy", mode="r+")["ecg"]
    altered[0, 0, 0] += 1.0
    assert any("stored ecg differs" in p for p in verify_store(copy, sample=2).problems)


def test_ecg_settings_are_checked_and_unset_keeps_the_hash(tiny_spec, reference_store):
    with pytest.raises(ConfigError, match=r"meshes \['lv'\] are surfaces"):
        tiny_spec(meshes=[{"id": "lv", "source": "lv", "nodes": 500, "kind": "triangle"}], output={"ecg": True})
    off = tiny_spec(output={"chunk_sites": 3, "sock_electrodes": 40, "ecg": False})
    assert off.output.ecg is None and spec_hash(off) == spec_hash(tiny_spec())
    assert "ecg" not in zarr.open_group(str(reference_store), path="subjects/lv-healthy").array_keys()


def test_the_reader_gives_the_ecgs_and_refuses_a_store_without(ecg_store, reference_store):
    from shared.errors import InputError
    from shared.reader import read_ecg

    ecg, names = read_ecg(ecg_store, "lv-healthy", [1, 4])
    stored = zarr.open_group(str(ecg_store), path="subjects/lv-healthy", mode="r")["ecg"][...]
    assert names == list(LEADS) and np.array_equal(ecg, stored[[1, 4]])
    with pytest.raises(InputError, match="has no ECG"):
        read_ecg(reference_store, "lv-healthy")
