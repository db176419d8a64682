"""Data for the surrogate: subject splits and meta-learning episodes read from a dataset store."""

from __future__ import annotations

from learner.data.episodes import OBSERVATION_SETS, Episode, EpisodeDataset, EpisodeSpec, load_episode
from learner.data.split import SPLITS, SplitSpec, split_subjects

__all__ = [
    "OBSERVATION_SETS",
    "SPLITS",
    "Episode",
    "EpisodeDataset",
    "EpisodeSpec",
    "SplitSpec",
    "load_episode",
    "split_subjects",
]
