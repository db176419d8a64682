"""Every shipped training config loads, and the anatomy config draws the sock as the real-heart test sees it."""

from __future__ import annotations

from pathlib import Path

import pytest

from learner.benchmark import RealDataSpec
from learner.config import load_config

SPECS = Path(__file__).resolve().parents[2] / "specs"


@pytest.mark.parametrize("name", sorted(p.name for p in SPECS.glob("train-*.toml")))
def test_shipped_training_configs_load(name):
    cfg = load_config(SPECS / name)
    assert cfg.train.epochs >= 1 and cfg.data.store.endswith(".zarr")


def test_the_anatomy_config_trains_on_the_surface_and_the_noisy_sock():
    episodes = load_config(SPECS / "train-anatomies.toml").data.episodes
    assert episodes.observe_sets == ("surface", "electrodes") and episodes.primary_observe == "surface"
    assert episodes.noise_std == RealDataSpec().noise_std == 0.02  # the real-data test's sock noise
