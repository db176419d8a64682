"""The tissue head's loss: cross-entropy against the stored scar nodes and the squared log-CV error, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from shared.tissue import ABNORMAL_LABELS, TissueSpec, healthy_speed


def _model_and_episode(store, tiny_config, out, tissue_loss=0.0):
    from learner.data.episodes import load_episode
    from learner.models.surrogate import build_model
    from learner.store_view import StoreView

    cfg = tiny_config(store, out, model={"tissue_head": True}, tissue_loss=tissue_loss)
    view = StoreView(store)
    ep = load_episode(store, "lv-scar-apex", [0, 1], [2, 3, 4], "surface")
    hier = view.hierarchy(ep.mesh_id, cfg.model.levels, cfg.model.coarsest)
    torch.manual_seed(0)
    return build_model(cfg.model, view.frames), ep, hier


def test_episodes_carry_the_stored_scar_nodes_and_the_healthy_speed(tiny_store):
    from learner.data.episodes import load_episode
    from shared.reader import read_tissue

    ep = load_episode(tiny_store, "lv-scar-apex", [0], [1], "surface")
    label = read_tissue(tiny_store, "lv-scar-apex").label
    np.testing.assert_array_equal(ep.abnormal.numpy(), np.isin(label, ABNORMAL_LABELS))
    assert 0 < int(ep.abnormal.sum()) < len(label)
    # the default tissue under the default solver: sqrt(2 k D)(1/2 - a) = sqrt(1600) 0.35 = 14 mm per time unit
    assert float(ep.cv) == pytest.approx(14.0 / 12.9, rel=1e-6)
    assert healthy_speed(TissueSpec(), 100.0) == pytest.approx(float(ep.cv), rel=1e-6)
    assert not load_episode(tiny_store, "lv-healthy", [0], [1], "surface").abnormal.any()


def test_tissue_loss_is_the_heads_bce_plus_squared_log_cv_error(tiny_store, tiny_config, tmp_path):
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run", tissue_loss=0.3)
    with torch.no_grad():  # a fresh head answers the same everywhere: perturb it so that its answers vary
        for p in model.tissue_head.parameters():
            p.add_(0.2 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))

    def terms(weight: float):
        return episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), tissue_weight=weight)

    with_tissue, without = terms(0.3), terms(0.0)
    torch.testing.assert_close(
        with_tissue.total - without.total, 0.3 * (with_tissue.tissue_bce + with_tissue.cv_log_error)
    )
    assert float(without.tissue_bce) == 0.0 and float(without.cv_log_error) == 0.0
    generator = torch.Generator().manual_seed(0)
    prior, _ = model.embed_prior_and_posterior(ep.context_obs, ep.target_u * ep.observed, ep.observed, hier)
    prior.sample(generator)  # the generator's draw comes first, then the head's
    with torch.no_grad():
        logit, log_cv = model.tissue(prior.sample(generator), hier)
    p, y = torch.sigmoid(logit).double(), ep.abnormal.double()
    hand = -(y * p.log() + (1 - y) * (1 - p).log()).mean()
    assert float(with_tissue.tissue_bce.detach()) == pytest.approx(float(hand), rel=1e-5)
    assert float(with_tissue.cv_log_error.detach()) == pytest.approx(
        (float(log_cv) - math.log(float(ep.cv))) ** 2, rel=1e-5
    )


def test_tissue_loss_trains_the_head_and_the_context_encoder(tiny_store, tiny_config, tmp_path):
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run", tissue_loss=0.3)
    terms = episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), tissue_weight=0.3)
    terms.total.backward()
    for part in (model.tissue_head.speed, model.tissue_head.decoder.out, model.context_encoder.mu):
        assert any(float(p.grad.abs().sum()) > 0 for p in part.parameters()), part


def test_a_fresh_head_starts_at_the_default_speed_on_any_mesh(tiny_store, tiny_config, tmp_path):
    from learner.models.tissue_head import DEFAULT_CV

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    c = torch.randn(hier.graphs[-1].num_nodes, model.config.latent)
    logit, log_cv = model.tissue(c, hier)
    assert logit.shape == (ep.context_u.shape[-1],)
    assert float(torch.exp(log_cv)) == pytest.approx(DEFAULT_CV)
    assert float(torch.sigmoid(logit).mean()) == pytest.approx(1 / (1 + math.exp(2.0)), rel=1e-4)


def test_tissue_loss_needs_a_tissue_head(tiny_store, tiny_config, tmp_path):
    from learner.models.surrogate import build_model
    from learner.train.loss import episode_loss
    from shared.errors import ConfigError

    with pytest.raises(ConfigError, match="model.tissue_head"):
        tiny_config(tiny_store, tmp_path / "run", tissue_loss=0.1)
    with pytest.raises(ConfigError, match="tissue_loss must be >= 0"):
        tiny_config(tiny_store, tmp_path / "run", model={"tissue_head": True}, tissue_loss=-1.0)
    with pytest.raises(ConfigError, match="tissue_head"):
        tiny_config(tiny_store, tmp_path / "run", kind="pns", model={"tissue_head": True})
    _, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    plain = build_model(tiny_config(tiny_store, tmp_path / "run").model, 12)
    with pytest.raises(ValueError, match="infers no tissue|has none"):
        episode_loss(plain, ep, hier, 0.3, 0.7, tissue_weight=0.1)
