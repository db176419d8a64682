"""Episodes: contents against the store, determinism, worker sharding, I/O bounds, refusals."""

from __future__ import annotations

import pickle
import pickletools
from pathlib import Path

import numpy as np
import pytest
import torch
import zarr
from torch.utils.data import DataLoader
from zarr.storage import LocalStore

from learner.data import Episode, EpisodeDataset, EpisodeSpec, SplitSpec, load_episode, split_subjects
from shared.errors import InputError, SchemaError
from shared.reader import read_index_set, read_sites, subject_attrs, subject_ids

SPEC = EpisodeSpec(context=(1, 3), targets=6, observe="epicardium")


def _truth(store: Path, sid: str) -> np.ndarray:
    # The whole u of a tiny subject, read independently of the code under test.
    return zarr.open_group(str(store), path=f"subjects/{sid}", mode="r")["u"][...]


def _same(a: Episode, b: Episode) -> bool:
    names = ["context_sites", "context_obs", "observed", "context_u", "target_sites", "target_u", "times"]
    return a.subject_id == b.subject_id and all(torch.equal(getattr(a, n), getattr(b, n)) for n in names)


@pytest.fixture(scope="module")
def train_subjects(tiny_store: Path) -> list[str]:
    ids = subject_ids(tiny_store)
    parts = split_subjects(ids, {s: subject_attrs(tiny_store, s)["mesh_id"] for s in ids}, SplitSpec(seed=0))
    return parts["train"]


def test_episode_matches_the_store(tiny_store):
    ids = subject_ids(tiny_store)
    ds = EpisodeDataset(tiny_store, ids, SPEC, seed=7, episodes_per_subject=3)
    seen_sizes = set()
    for ep in ds:
        mesh_id = subject_attrs(tiny_store, ep.subject_id)["mesh_id"]
        u, stim = _truth(tiny_store, ep.subject_id), read_sites(tiny_store, mesh_id)
        k, m = ep.context_rows.numel(), ep.target_rows.numel()
        seen_sizes.add(k)
        assert 1 <= k <= 3 and m == 6
        assert not set(ep.context_rows.tolist()) & set(ep.target_rows.tolist())
        assert ep.context_u.shape == (k, 12, u.shape[2]) and ep.target_u.shape == (m, 12, u.shape[2])
        for t in (ep.context_obs, ep.context_u, ep.target_u, ep.times):
            assert t.dtype == torch.float32
        assert ep.context_sites.dtype == torch.long and ep.observed.dtype == torch.bool
        np.testing.assert_array_equal(ep.context_u.numpy(), u[ep.context_rows.numpy()])
        np.testing.assert_array_equal(ep.target_u.numpy(), u[ep.target_rows.numpy()])
        np.testing.assert_array_equal(ep.context_sites.numpy(), stim[ep.context_rows.numpy()])
        np.testing.assert_array_equal(ep.target_sites.numpy(), stim[ep.target_rows.numpy()])
        epicardium = np.sort(read_index_set(tiny_store, mesh_id, "epicardium"))
        np.testing.assert_array_equal(np.flatnonzero(ep.observed.numpy()), epicardium)
        assert 0 < ep.observed.sum() < ep.observed.numel()
        expected_obs = ep.context_u.clone()
        expected_obs[:, :, ~ep.observed] = 0
        assert torch.equal(ep.context_obs, expected_obs)
        np.testing.assert_allclose(ep.times.numpy(), np.arange(1, 13) * 2.0)
    assert seen_sizes == {1, 2, 3}
    assert "context=" in repr(ep) and ep.subject_id in repr(ep)
    moved = ep.to("cpu")
    assert _same(moved, ep) and moved.context_rows is not None


def test_noise_only_on_observed_nodes_and_reproducible(tiny_store):
    spec = EpisodeSpec(context=(2, 2), targets=2, observe="epicardium", noise_std=0.05)
    a = EpisodeDataset(tiny_store, ["lv-healthy"], spec, seed=1).episode(0)
    b = EpisodeDataset(tiny_store, ["lv-healthy"], spec, seed=1).episode("lv-healthy")
    assert _same(a, b)
    diff = (a.context_obs - a.context_u)[:, :, a.observed]
    assert abs(diff.std().item() - 0.05) < 0.005 and abs(diff.mean().item()) < 0.005
    assert torch.all(a.context_obs[:, :, ~a.observed] == 0)
    with_rng = load_episode(tiny_store, "lv-healthy", [0, 1], [2], "all", 0.05, np.random.default_rng(0))
    again = load_episode(tiny_store, "lv-healthy", [0, 1], [2], "all", 0.05, np.random.default_rng(0))
    assert _same(with_rng, again) and not torch.equal(with_rng.context_obs, with_rng.context_u)
    with pytest.raises(InputError, match="needs an rng"):
        load_episode(tiny_store, "lv-healthy", [0], [1], "all", 0.05)


def test_episode_depends_only_on_seed_epoch_subject_k(tiny_store, train_subjects):
    ds = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=3, epoch=2, episodes_per_subject=2)
    streamed = list(ds)
    assert len(streamed) == len(ds) == 2 * len(train_subjects)
    # rebuilt out of order, from a fresh object: identical
    fresh = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=3, epoch=2, episodes_per_subject=2)
    for pos, (k, i) in reversed(list(enumerate((k, i) for k in range(2) for i in ds.order()))):
        assert _same(streamed[pos], fresh.episode(i, k))
    ds.set_epoch(3)
    assert ds.order() != fresh.order() or any(not _same(a, b) for a, b in zip(streamed, ds))
    n = len(train_subjects)
    assert any(not _same(fresh.episode(i, 0), ds.episode(i, 0)) for i in range(n))  # same subject, new epoch
    other_seed = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=4, epoch=2, episodes_per_subject=2)
    assert any(not _same(a, b) for a, b in zip(streamed, other_seed))


def test_dataloader_workers_visit_each_subject_once(tiny_store, train_subjects):
    ds = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=11)
    loader = DataLoader(ds, batch_size=None, num_workers=2)

    def run(epoch: int) -> list[Episode]:
        ds.set_epoch(epoch)
        return list(loader)

    first, again, second = run(0), run(0), run(1)
    for episodes in (first, second):
        assert sorted(e.subject_id for e in episodes) == sorted(train_subjects)
    assert all(_same(a, b) for a, b in zip(first, again)) and len(first) == len(again)
    by_subject = {e.subject_id: e for e in second}
    assert any(not _same(e, by_subject[e.subject_id]) for e in first)
    # the same episodes as without workers (sharding changes only the interleaving)
    ds.set_epoch(0)
    single = {e.subject_id: e for e in ds}
    assert all(_same(e, single[e.subject_id]) for e in first)


def test_persistent_workers_follow_set_epoch(tiny_store, train_subjects):
    ds = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=2)
    loader = DataLoader(ds, batch_size=None, num_workers=1, persistent_workers=True)
    for epoch in (0, 1, 0, 3):  # the same worker process each time
        ds.set_epoch(epoch)
        streamed = list(loader)
        expected = [ds.episode(i) for i in ds.order()]
        assert len(streamed) == len(expected) and all(_same(a, b) for a, b in zip(streamed, expected))


def test_dataset_pickles_without_zarr_objects(tiny_store):
    ds = EpisodeDataset(tiny_store, ["lv-healthy"], SPEC, seed=0)
    list(ds)  # iterating in this process must not leave open handles on the object
    blob = pickle.dumps(ds)
    strings = [arg for _, arg, _ in pickletools.genops(blob) if isinstance(arg, str)]
    assert not [s for s in strings if s.startswith(("zarr", "numcodecs"))]  # no zarr class inside
    assert len(blob) < 20_000
    clone = pickle.loads(blob)
    assert _same(clone.episode(0), ds.episode(0))
    assert repr(ds).startswith("EpisodeDataset(store=") and "subjects=1" in repr(ds) and "epicardium" in repr(ds)


@pytest.fixture
def chunk_reads(monkeypatch) -> list[str]:
    """Keys of ``u`` chunks read from any local store while the test runs."""
    keys: list[str] = []
    original = LocalStore.get

    async def get(self, key, *args, **kwargs):
        if "/u/c/" in key:
            keys.append(key)
        return await original(self, key, *args, **kwargs)

    monkeypatch.setattr(LocalStore, "get", get)
    return keys


def test_reads_only_the_chunks_of_the_selected_rows(tiny_store, chunk_reads):
    load_episode(tiny_store, "lv-healthy", [1], [2, 3])  # rows 0-3 = shard 0
    assert set(chunk_reads) == {"subjects/lv-healthy/u/c/0/0/0"}  # per row: the shard index, the row's inner chunk
    chunk_reads.clear()
    load_episode(tiny_store, "lv-healthy", [9], [0])
    assert set(chunk_reads) == {"subjects/lv-healthy/u/c/0/0/0", "subjects/lv-healthy/u/c/2/0/0"}
    chunk_reads.clear()
    spec = EpisodeSpec(context=(1, 2), targets=2, chunks_per_episode=1)
    ds = EpisodeDataset(tiny_store, ["lv-healthy", "lv-b-scar-apex"], spec, seed=5, episodes_per_subject=4)
    assert chunk_reads == []  # construction reads metadata only
    episodes = list(ds)
    assert len(episodes) == 8 and len(set(chunk_reads)) <= 8  # one shard per episode
    for ep in episodes:
        rows = torch.cat([ep.context_rows, ep.target_rows])
        assert len(set((rows // 4).tolist())) == 1


def test_observation_mixture_draws_one_set_per_episode(tiny_store, train_subjects):
    mixed = EpisodeSpec(context=(1, 3), targets=6, observe=["epicardium", "all"], noise_std=0.05)
    assert mixed.observe == ("epicardium", "all") and mixed.observe_sets == mixed.observe
    assert mixed.primary_observe == "epicardium"
    assert EpisodeSpec(observe=["surface"]).observe == "surface" == EpisodeSpec().primary_observe
    one = EpisodeDataset(tiny_store, train_subjects, SPEC, seed=5, episodes_per_subject=4)
    ds = EpisodeDataset(tiny_store, train_subjects, mixed, seed=5, episodes_per_subject=4)
    picked = []
    for k in range(4):
        for i in range(len(train_subjects)):
            ep, single = ds.episode(i, k), one.episode(i, k)
            # the set is drawn after the sites: same sites as a one-set spec with the same seed
            assert torch.equal(ep.context_rows, single.context_rows) and torch.equal(ep.target_rows, single.target_rows)
            mesh_id = subject_attrs(tiny_store, ep.subject_id)["mesh_id"]
            epicardium = np.zeros(ep.observed.numel(), bool)
            epicardium[read_index_set(tiny_store, mesh_id, "epicardium")] = True
            is_epi = np.array_equal(ep.observed.numpy(), epicardium)
            assert is_epi or bool(ep.observed.all())
            assert torch.all(ep.context_obs[:, :, ~ep.observed] == 0)
            assert _same(ep, ds.episode(i, k))  # reproducible, mask included
            picked.append(is_epi)
    assert 0 < sum(picked) < len(picked)  # both sets are drawn


@pytest.mark.parametrize(
    ("observe", "match"),
    [
        ([], "a list of distinct ones"),
        (["surface", "surface"], "distinct"),
        (3, "observation set or a list"),
        (["surface", "sock"], "unknown observation set 'sock'"),
    ],
)
def test_refuses_bad_observation_mixtures(observe, match):
    with pytest.raises(InputError, match=match):
        EpisodeSpec(observe=observe)


def test_refuses_bad_specs():
    with pytest.raises(InputError, match="context size must be >= 1"):
        EpisodeSpec(context=(0, 3))
    with pytest.raises(InputError, match="context max must be >= context min"):
        EpisodeSpec(context=(3, 2))
    with pytest.raises(InputError, match="unknown observation set 'sock'"):
        EpisodeSpec(observe="sock")
    with pytest.raises(InputError, match="noise_std"):
        EpisodeSpec(noise_std=-1.0)
    with pytest.raises(InputError, match="chunks_per_episode"):
        EpisodeSpec(chunks_per_episode=-1)
    assert EpisodeSpec(context=[2, 4]).context == (2, 4)


def test_refuses_bad_datasets(tiny_store):
    with pytest.raises(InputError, match=r"needs up to 5 context \+ 20 targets = 25 sites, but it has 12"):
        EpisodeDataset(tiny_store, ["lv-healthy"], EpisodeSpec(), seed=0)
    with pytest.raises(InputError, match="1 chunk.* of 4 sites hold as few as 4"):
        EpisodeDataset(tiny_store, ["lv-healthy"], EpisodeSpec(context=(1, 2), targets=3, chunks_per_episode=1), seed=0)
    with pytest.raises(InputError, match="unknown subject.*lv-nobody"):
        EpisodeDataset(tiny_store, ["lv-healthy", "lv-nobody"], SPEC, seed=0)
    with pytest.raises(InputError, match="list of subject ids"):
        EpisodeDataset(tiny_store, "lv-healthy", SPEC, seed=0)
    with pytest.raises(InputError, match="at least one subject"):
        EpisodeDataset(tiny_store, [], SPEC, seed=0)
    with pytest.raises(InputError, match="duplicate"):
        EpisodeDataset(tiny_store, ["lv-healthy", "lv-healthy"], SPEC, seed=0)
    with pytest.raises(InputError, match="seed"):
        EpisodeDataset(tiny_store, ["lv-healthy"], SPEC, seed=-1)
    with pytest.raises(InputError, match="epoch"):
        EpisodeDataset(tiny_store, ["lv-healthy"], SPEC, seed=0).set_epoch(-1)


@pytest.mark.parametrize(
    "context, targets, kwargs, match",
    [
        ([], [1], {}, "context size must be >= 1"),
        ([0, 1], [1, 2], {}, r"must not include context sites; both have rows \[1\]"),
        ([12], [1], {}, r"outside the subject's site rows \[0, 12\)"),
        ([1, 1], [2], {}, "repeated"),
        ([1], [2], {"observe": "sock"}, "unknown observation set"),
    ],
)
def test_load_episode_refusals(tiny_store, context, targets, kwargs, match):
    with pytest.raises(InputError, match=match):
        load_episode(tiny_store, "lv-healthy", context, targets, **kwargs)


def test_load_episode_unknown_subject(tiny_store):
    with pytest.raises(InputError, match="unknown subject 'nobody'"):
        load_episode(tiny_store, "nobody", [0], [1])


def test_missing_chunk_is_refused(store_copy):
    zarr.open_group(str(store_copy), path="subjects/lv-scar-apex", mode="r+")["done"][1] = 0
    with pytest.raises(SchemaError, match=r"subject 'lv-scar-apex' has unfinished chunk\(s\) 1 \(done == 0\)"):
        EpisodeDataset(store_copy, ["lv-healthy", "lv-scar-apex"], SPEC, seed=0)
    EpisodeDataset(store_copy, ["lv-healthy"], SPEC, seed=0)  # other subjects are fine
    with pytest.raises(SchemaError, match=r"unfinished chunk\(s\) 1"):
        load_episode(store_copy, "lv-scar-apex", [0], [5])  # row 5 is in chunk 1
    ep = load_episode(store_copy, "lv-scar-apex", [0], [9])  # chunks 0 and 2 are done
    assert ep.target_u.shape[0] == 1


def test_wrong_schema_version_is_refused(store_copy):
    zarr.open_group(str(store_copy), mode="r+").attrs["schema_version"] = 99
    with pytest.raises(SchemaError, match="schema_version 99"):
        EpisodeDataset(store_copy, ["lv-healthy"], SPEC, seed=0)
    with pytest.raises(SchemaError, match="schema_version 99"):
        load_episode(store_copy, "lv-healthy", [0], [1])
