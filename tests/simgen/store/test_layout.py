"""The store layout a build writes before any task runs, and the chunk list read back from it."""

from __future__ import annotations

import errno
import gc
import os

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec
from zarr.storage import LocalStore

from shared.schema import SCHEMA_VERSION
from simgen.store import make_plan, spec_hash
from simgen.store.layout import chunk_tasks, create_layout, pending_tasks
from simgen.store.manifest import Task
from simgen.store.spec import spec_to_dict
from simgen.tissue import tissue_fields


def test_layout_groups_arrays_and_fields(tmp_path, tiny_spec):
    spec = tiny_spec(output={"chunk_sites": 4, "sock_electrodes": 40, "compressor": "blosc"})
    plan = make_plan(spec)
    store = tmp_path / "s.zarr"
    assert create_layout(store, plan, spec_to_dict(spec), spec_hash(spec))  # fields computed here
    root = zarr.open_group(str(store), mode="r")
    # the subject groups are created at once below an existing root: its attributes stay
    assert root.attrs["schema_version"] == SCHEMA_VERSION and root.attrs["spec_hash"] == spec_hash(spec)
    assert sorted(root["subjects"]) == ["lv-healthy", "lv-scar-apex"]
    mesh, frames = plan.meshes["lv"], spec.solver.frames
    n = mesh.n_nodes
    for subject in plan.subjects:
        g = root[f"subjects/{subject.id}"]
        assert (g.attrs["mesh_id"], g.attrs["chunk_sites"], g.attrs["tissue"]["name"]) == ("lv", 4, subject.tissue.name)
        u, act, done = g["u"], g["activation"], g["done"]
        assert (u.shape, u.shards, u.chunks, u.metadata.dimension_names) == (
            (6, frames, n),
            (4, frames, n),  # one shard per build task
            (1, frames, n),  # one inner chunk per site
            ("site", "time", "node"),
        )
        assert (act.shape, act.shards, act.chunks) == ((6, n), (4, n), (1, n))
        assert np.isnan(u.fill_value) and np.isnan(act.fill_value)
        assert isinstance(u.compressors[0], BloscCodec) and isinstance(u.compressors[-1], Crc32cCodec)
        assert (done.shape, done.chunks, done.fill_value, done.compressors) == ((2,), (1,), 0, (Crc32cCodec(),))
        assert np.isnan(u[...]).all() and not done[...].any()  # nothing simulated yet
        fields = tissue_fields(mesh, subject.tissue)
        for name in ("a", "D", "label"):
            assert np.array_equal(g[name][...], np.asarray(getattr(fields, name), g[name].dtype))
        assert np.allclose(g["times"][...], spec.solver.output_interval * np.arange(1, frames + 1))


def test_chunk_tasks_lists_every_chunk_with_its_flag(tmp_path, tiny_spec):
    spec = tiny_spec()
    store = tmp_path / "s.zarr"
    create_layout(store, make_plan(spec), spec_to_dict(spec), spec_hash(spec))
    zarr.open_group(str(store), path="subjects/lv-scar-apex", mode="r+")["done"][1] = 1
    expected = {
        Task("lv-healthy", 0, 0, 3): False,
        Task("lv-healthy", 1, 3, 6): False,
        Task("lv-scar-apex", 0, 0, 3): False,
        Task("lv-scar-apex", 1, 3, 6): True,
    }
    assert list(chunk_tasks(store).items()) == list(expected.items())  # subject then chunk order
    assert chunk_tasks(store, ["lv-scar-apex"]) == {t: d for t, d in expected.items() if t.subject_id == "lv-scar-apex"}
    assert pending_tasks(store) == [t for t, d in expected.items() if not d]


def test_a_full_disk_during_the_layout_is_one_error(tmp_path, tiny_spec, monkeypatch, caplog):
    spec = tiny_spec()
    real = LocalStore.set

    async def full(self, key, value, *args, **kw):
        if key.startswith("subjects/lv-"):  # the subject groups, written at once: the disk fills among them
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), key)
        return await real(self, key, value, *args, **kw)

    monkeypatch.setattr(LocalStore, "set", full)
    with pytest.raises(OSError, match="No space left on device"):
        create_layout(tmp_path / "s.zarr", make_plan(spec), spec_to_dict(spec), spec_hash(spec))
    gc.collect()  # the writes zarr abandoned after the first failure: none reported again
    assert "never retrieved" not in caplog.text and "Traceback" not in caplog.text
