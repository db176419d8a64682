"""SimulationDataset: one simulation per item, subsets, normalisation, collates, DataLoader workers."""

from __future__ import annotations

import pickle
import shutil
from functools import partial

import numpy as np
import pytest
import torch
import zarr
from torch.utils.data import DataLoader

from shared.dataset import NODE_AXES, SimulationDataset, collate_graphs, collate_padded, subset_statistics
from shared.errors import InputError
from shared.reader import (
    read_activation,
    read_mesh,
    read_sites,
    read_split,
    read_statistics,
    read_times,
    read_tissue,
    read_u,
    subject_ids,
)


def test_an_item_is_one_simulation_of_the_store(tiny_store):
    ds = SimulationDataset(tiny_store, edges=True)
    assert len(ds) == 6 * 12 and ds.subjects == subject_ids(tiny_store)
    i = 12 + 5  # second subject, site row 5
    item, sid = ds[i], ds.subjects[1]
    mesh_id = ds.mesh_of[sid]
    assert (item["subject"], item["mesh"], item["site_index"]) == (sid, mesh_id, 5)
    assert item["site"] == read_sites(tiny_store, mesh_id)[5]
    np.testing.assert_array_equal(item["u"], read_u(tiny_store, sid, [5])[0])
    np.testing.assert_array_equal(item["activation"], read_activation(tiny_store, sid, [5])[0])
    np.testing.assert_array_equal(item["times"], read_times(tiny_store, sid).astype(np.float32))
    np.testing.assert_array_equal(item["time_ms"], read_times(tiny_store, sid, "ms").astype(np.float32))
    tissue, mesh = read_tissue(tiny_store, sid), read_mesh(tiny_store, mesh_id)
    np.testing.assert_array_equal(item["a"], tissue.a.astype(np.float32))
    np.testing.assert_array_equal(item["label"], tissue.label)
    np.testing.assert_array_equal(item["points"], mesh.points.astype(np.float32))
    np.testing.assert_array_equal(item["edges"], mesh.edges())
    np.testing.assert_array_equal(ds.mesh(mesh_id).cells, mesh.cells)
    assert item["u"].shape == (12, mesh.n_nodes) and item["u"].dtype == np.float32
    item["a"][:] = 0  # an item is the caller's to change
    assert ds[i]["a"].max() > 0
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_subsets_by_split_or_subject_ids(tiny_store):
    parts = read_split(tiny_store)
    train = SimulationDataset(tiny_store, split="train")
    assert train.subjects == [sid for sid in subject_ids(tiny_store) if parts[sid] == "train"]
    chosen = SimulationDataset(tiny_store, subjects=["lv-scar-apex", "lv-b-healthy"])
    assert chosen.subjects == ["lv-scar-apex", "lv-b-healthy"] and len(chosen) == 24
    assert chosen[12]["subject"] == "lv-b-healthy"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"split": "train", "subjects": ["lv-healthy"]}, "not both"),
        ({"split": "holdout"}, "unknown split 'holdout'"),
        ({"subjects": ["lv-nobody"]}, "unknown subject.*lv-nobody"),
        ({"subjects": "lv-healthy"}, "not the string"),
        ({"subjects": []}, "has no subjects"),
        ({"normalize": True, "statistics": {"u": {"mean": 0.0, "std": 0.0}}}, "non-zero std"),
    ],
)
def test_bad_subsets_are_refused(tiny_store, kwargs, match):
    with pytest.raises(InputError, match=match):
        SimulationDataset(tiny_store, **kwargs)


def test_unfinished_chunks_are_left_out(tiny_store, tmp_path):
    store = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, store)
    zarr.open_group(str(store), path="subjects/lv-healthy", mode="r+")["done"][1] = 0  # site rows 4-7
    ds = SimulationDataset(store, subjects=["lv-healthy"])
    assert [ds[i]["site_index"] for i in range(len(ds))] == [0, 1, 2, 3, 8, 9, 10, 11]


def test_a_damaged_done_flag_is_named_with_its_chunk_and_the_repair(tiny_store, tmp_path):
    from shared.errors import DamagedData

    store = tmp_path / "copy.zarr"
    shutil.copytree(tiny_store, store)
    flag = store / "subjects/lv-healthy/done/c/1"
    data = bytearray(flag.read_bytes())
    data[-1] ^= 0xFF  # its CRC32C no longer matches
    flag.write_bytes(bytes(data))
    with pytest.raises(
        DamagedData, match=r"array done, site of chunk 1 \(file subjects/lv-healthy/done/c/1\).*simgen repair"
    ):
        SimulationDataset(store, subjects=["lv-healthy"])


def test_normalisation_with_store_or_subset_statistics(tiny_store):
    raw, scaled = SimulationDataset(tiny_store)[3], SimulationDataset(tiny_store, normalize=True)[3]
    stats = read_statistics(tiny_store)
    for name in ("u", "activation"):
        expected = (raw[name] - stats[name]["mean"]) / stats[name]["std"]
        np.testing.assert_allclose(scaled[name], expected, rtol=1e-6, atol=1e-6)
    combined = subset_statistics(tiny_store, subject_ids(tiny_store))  # every subject: the store's statistics
    for name in ("u", "activation"):
        assert combined[name]["count"] == stats[name]["count"]
        assert combined[name]["min"] == stats[name]["min"] and combined[name]["max"] == stats[name]["max"]
        np.testing.assert_allclose(
            [combined[name]["mean"], combined[name]["std"]], [stats[name]["mean"], stats[name]["std"]]
        )
    one, own = subset_statistics(tiny_store, ["lv-healthy"]), read_statistics(tiny_store, "lv-healthy")
    np.testing.assert_allclose([one["u"]["mean"], one["u"]["std"]], [own["u"]["mean"], own["u"]["std"]])


def test_collates_join_or_pad_meshes_of_different_sizes(tiny_store):
    ds = SimulationDataset(tiny_store, subjects=["lv-healthy", "lv-b-healthy"], edges=True)
    items = [ds[0], ds[12], ds[1]]
    sizes = [len(item["points"]) for item in items]
    assert sizes[0] != sizes[1]
    graph = collate_graphs(items)
    assert graph["u"].shape == (12, sum(sizes)) and graph["points"].shape == (sum(sizes), 3)
    assert graph["ptr"].tolist() == [0, sizes[0], sizes[0] + sizes[1], sum(sizes)]
    assert torch.bincount(graph["batch"]).tolist() == sizes
    second = graph["edges"][len(items[0]["edges"]) : len(items[0]["edges"]) + len(items[1]["edges"])]
    assert torch.equal(second, torch.as_tensor(items[1]["edges"]) + sizes[0])
    assert graph["subject"] == ["lv-healthy", "lv-b-healthy", "lv-healthy"] and graph["times"].shape == (3, 12)
    padded = collate_padded(items)
    assert padded["u"].shape == (3, 12, max(sizes)) and padded["mask"].sum(dim=1).tolist() == sizes
    assert torch.equal(padded["u"][0, :, : sizes[0]], torch.as_tensor(items[0]["u"]))
    assert not padded["activation"][0, sizes[0] :].any() and len(padded["edges"]) == 3


def _with_degree(item: dict) -> dict:
    return {**item, "degree": np.ones(len(item["a"]), np.float32)}


def test_pickles_without_zarr_objects_and_feeds_dataloader_workers(tiny_store):
    ds = SimulationDataset(tiny_store, split="train", transform=_with_degree)
    ds[0]  # opens array handles, which must stay in this process
    blob = pickle.dumps(ds)
    assert b"zarr.core" not in blob and b"numcodecs" not in blob
    np.testing.assert_array_equal(pickle.loads(blob)[7]["u"], ds[7]["u"])
    collate = partial(collate_graphs, node_axes={**NODE_AXES, "degree": 0})
    batches = list(DataLoader(ds, batch_size=5, num_workers=2, collate_fn=collate))
    seen = [(s, int(r)) for b in batches for s, r in zip(b["subject"], b["site_index"])]
    assert sorted(seen) == sorted((ds[i]["subject"], ds[i]["site_index"]) for i in range(len(ds)))
    assert sum(len(b["degree"]) for b in batches) == sum(len(ds[i]["a"]) for i in range(len(ds)))
