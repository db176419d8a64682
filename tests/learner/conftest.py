"""A small model configuration on the tiny store of ``tests/conftest.py``, and untrained models made to act trained."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch


def tiny_toml(store: Path, workers: int = 0, validation: float = 0.2, test: float = 0.2, train: str = "") -> str:
    """:func:`tiny_config`'s model as a TOML file's text (``out = "run"``); ``train``: lines of ``[train]``."""
    return f"""
out = "run"
[data]
store = "{store}"
workers = {workers}
[data.split]
seed = 0
validation = {validation}
test = {test}
[data.episodes]
context = [1, 3]
targets = 4
[model]
channels = [4, 8]
hidden = 16
latent = 8
levels = 3
coarsest = 10
coarse_blocks = 1
[train]
{train}
"""


def tiny_config(store: Path, out: Path, kind: str = "metapns", model: dict | None = None, **train):
    """A small model (``model``: more model keys) and short training on :func:`tiny_store` (seconds per epoch)."""
    from learner.config import config_from_mapping

    return config_from_mapping(
        {
            "out": str(out),
            "data": {
                "store": str(store),
                "workers": 0,
                "split": {"seed": 0, "validation": 0.2, "test": 0.2},
                "episodes": {"context": [1, 3], "targets": 4, "observe": "surface"},
            },
            "model": {
                "kind": kind,
                "channels": [4, 8],
                "hidden": 16,
                "latent": 8,
                "levels": 3,
                "coarsest": 10,
                "coarse_blocks": 1,
                **(model or {}),
            },
            "train": {"epochs": 2, "validate_every": 1, **train},
        }
    )


@pytest.fixture(name="tiny_config", scope="session")
def tiny_config_fixture():
    """The :func:`tiny_config` factory."""
    return tiny_config


@pytest.fixture(name="tiny_toml", scope="session")
def tiny_toml_fixture():
    """The :func:`tiny_toml` factory."""
    return tiny_toml


def trained_like(model):
    """``model`` with a trained-like random output layer: a fresh decoder (zero output weights) predicts a constant."""
    with torch.no_grad():
        model.decoder.out.weight.normal_(0.0, 0.5)
    return model


@pytest.fixture(name="trained_like", scope="session")
def trained_like_fixture():
    """The :func:`trained_like` helper."""
    return trained_like
