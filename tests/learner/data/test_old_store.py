"""The learner keeps reading version-1 stores (the stores built before schema version 2)."""

from __future__ import annotations

import warnings

import pytest
import torch

from learner.data import EpisodeDataset, EpisodeSpec, SplitSpec, split_subjects
from learner.store_view import StoreView
from shared.errors import InputError
from shared.schema import SchemaWarning


def test_version_1_store_gives_the_same_episodes(tiny_store, store_copy, as_version_1):
    as_version_1(store_copy)
    with pytest.warns(SchemaWarning, match="schema_version 1"):
        old = StoreView(store_copy)
    new = StoreView(tiny_store)
    assert (old.subjects, old.mesh_of, old.frames) == (new.subjects, new.mesh_of, new.frames)
    assert torch.equal(torch.as_tensor(old.times), torch.as_tensor(new.times))
    spec = EpisodeSpec(context=(1, 3), targets=4, observe="surface")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchemaWarning)
        old_episode = EpisodeDataset(store_copy, old.subjects, spec, seed=3).episode(0)
    new_episode = EpisodeDataset(tiny_store, new.subjects, spec, seed=3).episode(0)
    assert torch.equal(old_episode.target_u, new_episode.target_u)
    assert torch.equal(old_episode.context_obs, new_episode.context_obs)
    computed = SplitSpec(seed=0)
    assert split_subjects(old.subjects, old.mesh_of, computed) == split_subjects(new.subjects, new.mesh_of, computed)
    assert old.stored_split == {} and len(new.stored_split) == 6
    with pytest.raises(InputError, match="records no split.*rebuild it with `simgen build`"):
        split_subjects(old.subjects, old.mesh_of, SplitSpec(source="store"), old.stored_split)
