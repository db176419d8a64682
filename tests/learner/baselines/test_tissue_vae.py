"""Tissue VAE: shapes, admissible decoded maps, a useful reconstruction, reproducible training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.baselines.tissue_library import scar_library
from learner.baselines.tissue_vae import TissueVAE, train_tissue_vae
from shared.errors import InputError


@pytest.fixture(scope="module")
def library(lv) -> np.ndarray:
    return scar_library(lv.mesh, count=120, seed=0)


def test_trained_vae_reconstructs_scars_better_than_the_mean_map(library):
    state = torch.get_rng_state()
    vae = train_tissue_vae(library, latent=3, epochs=60, seed=0)
    assert torch.equal(torch.get_rng_state(), state)
    assert repr(vae) == f"TissueVAE(nodes={library.shape[1]}, latent=3, hidden=128)"
    with torch.no_grad():
        mu, logvar = vae.encode(torch.from_numpy((library - 0.15) / 0.35))
    assert mu.shape == logvar.shape == (len(library), 3)
    rec = vae.decode(mu.numpy())
    assert rec.shape == library.shape and rec.min() >= 0.15 and rec.max() <= 0.5
    assert vae.decode(np.zeros(3)).shape == (library.shape[1],)
    assert np.mean((rec - library) ** 2) < 0.5 * np.mean((library.mean(axis=0) - library) ** 2)
    again = train_tissue_vae(library, latent=3, epochs=60, seed=0)
    np.testing.assert_array_equal(again.decode(np.ones(3)), vae.decode(np.ones(3)))


def test_refuses_bad_input(library):
    with pytest.raises(InputError, match="maps must be"):
        train_tissue_vae(library[:1])
    with pytest.raises(InputError, match="NaN"):
        train_tissue_vae(np.where(library == 0.5, np.nan, library))
    with pytest.raises(InputError, match="latent points"):
        TissueVAE(10, latent=2).decode(np.zeros(3))
