"""The KL terms against torch.distributions, the loss normalised per node and frame, and the capture gate's loss."""

from __future__ import annotations

import pytest
import torch
from torch.distributions import Normal, kl_divergence

from learner.models.surrogate import Posterior
from learner.train.loss import gaussian_kl, standard_normal_kl


def test_gaussian_kl_matches_torch_distributions():
    g = torch.Generator().manual_seed(0)
    q = Posterior(torch.randn(5, 3, generator=g), torch.randn(5, 3, generator=g))
    p = Posterior(torch.randn(5, 3, generator=g), torch.randn(5, 3, generator=g))
    ref = kl_divergence(Normal(q.mu, (0.5 * q.logvar).exp()), Normal(p.mu, (0.5 * p.logvar).exp())).sum()
    assert torch.allclose(gaussian_kl(q, p), ref, rtol=1e-5)
    std = kl_divergence(Normal(p.mu, (0.5 * p.logvar).exp()), Normal(0.0, 1.0)).sum()
    assert torch.allclose(standard_normal_kl(p), std, rtol=1e-5)
    assert float(gaussian_kl(q, q)) == 0.0


def test_posterior_sample_is_reparameterised():
    post = Posterior(torch.zeros(4, 2, requires_grad=True), torch.zeros(4, 2, requires_grad=True))
    c = post.sample(torch.Generator().manual_seed(1))
    c.sum().backward()
    assert torch.equal(post.mu.grad, torch.ones(4, 2)) and post.logvar.grad.abs().sum() > 0


def _model_and_episode(store, tiny_config, out, model=None):
    """A fresh metaPNS of the tiny config (``model``: more model keys), one episode (2 context, 3 targets) and its
    mesh hierarchy."""
    from learner.data.episodes import load_episode
    from learner.models.surrogate import build_model
    from learner.store_view import StoreView

    cfg = tiny_config(store, out, model=model)
    view = StoreView(store)
    ep = load_episode(store, "lv-scar-apex", [0, 1], [2, 3, 4], "surface")
    hier = view.hierarchy(ep.mesh_id, cfg.model.levels, cfg.model.coarsest)
    torch.manual_seed(0)
    return build_model(cfg.model, view.frames), ep, hier


def test_episode_loss_is_the_negative_elbo_per_node_and_frame(tiny_store, tiny_config, tmp_path):
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    terms = episode_loss(
        model, ep, hier, lambda1=0.3, lambda2=0.7, kl_weight=0.5, generator=torch.Generator().manual_seed(0)
    )
    c = model.embed_prior_and_posterior(ep.context_obs, ep.target_u * ep.observed, ep.observed, hier)[1].sample(
        torch.Generator().manual_seed(0)
    )
    pred = model.generate(torch.cat([ep.context_sites, ep.target_sites]), hier, c)
    truth = torch.cat([ep.context_u, ep.target_u])
    summed = ((pred - truth) ** 2).sum(dim=(1, 2))  # the reference's reconstruction: summed over nodes and frames
    elbo = summed[2:].mean() + summed[:2].mean() + 0.5 * (0.3 * terms.kl_posterior + 0.7 * terms.kl_prior)
    n_values = truth.shape[1] * truth.shape[2]
    torch.testing.assert_close(terms.total, elbo / n_values)
    assert float(terms.kl_prior.detach()) > 0


def test_c_from_context_generates_from_the_context_embedding(tiny_store, tiny_config, tmp_path):
    """``c_from="context"`` draws c from p(c | Y): the targets reach the loss only as targets and through KL(q || p)."""
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    torch.nn.init.normal_(model.decoder.out.weight, std=0.1)  # a fresh decoder ignores c (zero output weights)

    def terms(c_from: str):
        return episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), c_from=c_from)

    context, posterior = terms("context"), terms("posterior")
    prior = model.embed(ep.context_obs, ep.observed, hier)
    pred = model.generate(ep.target_sites, hier, prior.sample(torch.Generator().manual_seed(0)))
    torch.testing.assert_close(context.target_mse, ((pred - ep.target_u) ** 2).mean())
    torch.testing.assert_close(context.kl_posterior, posterior.kl_posterior)  # the same KL terms
    assert float(context.target_mse) != float(posterior.target_mse)


def test_maps_are_embedded_by_the_maps_encoder_of_a_model_that_has_one(tiny_store, tiny_config, tmp_path):
    """With a maps encoder, a maps episode's p(c | Y) is the maps encoder's reading of the maps up to each upstroke;
    q(c | Y u X), and p(c | Y) of a model without one, the context encoder's of every frame."""
    import dataclasses

    import numpy as np

    from learner.activation_maps import ApTemplate
    from learner.data.episodes import recorded_map
    from learner.train.loss import episode_loss

    for maps_encoder in (True, False):
        model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run", {"maps_encoder": maps_encoder})
        offsets = np.linspace(-40, 40, 801)
        template = ApTemplate(offsets, 1.0 / (1.0 + np.exp(-4.0 * offsets)) * (offsets < 20))
        u, times, observed = ep.context_u.numpy(), ep.times.numpy().astype(np.float64), ep.observed.numpy()
        obs, recorded = recorded_map(u, times, observed, template, 0.0, np.random.default_rng(0))
        maps = dataclasses.replace(ep, context_obs=torch.from_numpy(obs), context_recorded=torch.from_numpy(recorded))
        terms = episode_loss(model, maps, hier, 1.0, 1.0, reconstruction=False)
        extra = ep.target_u * ep.observed
        prior, posterior = model.embed_prior_and_posterior(maps.context_obs, extra, ep.observed, hier)
        if maps_encoder:
            prior = model.embed(maps.context_obs, ep.observed, hier, maps.context_recorded)
            assert not torch.equal(prior.mu, model.embed(maps.context_obs, ep.observed, hier).mu)
        torch.testing.assert_close(terms.kl_posterior, gaussian_kl(posterior, prior))
        torch.testing.assert_close(terms.kl_prior, standard_normal_kl(prior))


def test_gate_loss_is_the_gates_cross_entropy_against_waves_started(tiny_store, tiny_config, tmp_path):
    """``gate_bce`` by hand: -mean(y log g + (1 - y) log(1 - g)) over context and target sites, y from the truth."""
    from learner.metrics import wave_started
    from learner.models.site_evidence import SiteEvidence
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run", {"capture_gate": True})
    torch.nn.init.normal_(model.capture[-1].weight, std=1.0)  # a fresh gate is the same for every site

    def terms(weight: float):
        return episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), gate_weight=weight)

    with_gate, without = terms(0.5), terms(0.0)
    c = model.embed_prior_and_posterior(ep.context_obs, ep.target_u * ep.observed, ep.observed, hier)[1].sample(
        torch.Generator().manual_seed(0)
    )
    sites, truth = torch.cat([ep.context_sites, ep.target_sites]), torch.cat([ep.context_u, ep.target_u])
    g = torch.sigmoid(model.generate_with_gate(sites, hier, c, evidence=SiteEvidence.of(ep))[1]).double()
    y = torch.from_numpy(wave_started(truth.numpy())).double()
    assert 0 < float(g.min()) < float(g.max()) < 1
    hand = -(y * g.log() + (1 - y) * (1 - g).log()).mean()
    torch.testing.assert_close(with_gate.gate_bce.double(), hand, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(with_gate.total - without.total, 0.5 * with_gate.gate_bce)
    assert float(without.gate_bce) == 0.0


def test_gate_loss_teaches_the_gate_before_the_decoder_draws_waves(tiny_store, tiny_config, tmp_path):
    """A fresh model predicts the same sequence with and without a wave: the reconstruction gives the gate no
    gradient, the gate loss does."""
    from learner.train.loss import episode_loss

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run", {"capture_gate": True})
    model.set_output_mean(0.3)
    gate = model.capture[-1].weight
    for weight, moves in ((0.0, False), (0.1, True)):
        model.zero_grad()
        terms = episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), gate_weight=weight)
        terms.total.backward()
        assert (gate.grad is not None and float(gate.grad.abs().sum()) > 0) == moves, weight


def test_gate_loss_needs_a_capture_gate(tiny_store, tiny_config, tmp_path):
    from learner.train.loss import episode_loss
    from shared.errors import ConfigError

    with pytest.raises(ConfigError, match="model.capture_gate"):
        tiny_config(tiny_store, tmp_path / "run", gate_loss=0.1)
    with pytest.raises(ConfigError, match="gate_loss must be >= 0"):
        tiny_config(tiny_store, tmp_path / "run", model={"capture_gate": True}, gate_loss=-1.0)
    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    with pytest.raises(ValueError, match="has none"):
        episode_loss(model, ep, hier, 0.3, 0.7, gate_weight=0.1)


def test_spatial_correlation_is_the_metrics_cc_and_differentiable():
    """Against learner.metrics.spatial_cc (NumPy) on random frames, with constant true frames skipped."""
    from learner.metrics import spatial_cc
    from learner.train.loss import spatial_correlation

    g = torch.Generator().manual_seed(3)
    truth = torch.rand(4, 6, 50, generator=g, dtype=torch.float64)
    truth[1, 2] = 0.7  # a resting or fully excited frame: skipped by both
    pred = (0.5 * truth + 0.5 * torch.rand(4, 6, 50, generator=g, dtype=torch.float64)).requires_grad_()
    cc = spatial_correlation(pred, truth)
    assert abs(float(cc) - spatial_cc(pred.detach().numpy(), truth.numpy())) < 1e-9
    cc.backward()
    assert torch.isfinite(pred.grad).all() and float(pred.grad[1, 2].abs().sum()) == 0.0
    assert float(spatial_correlation(truth, truth)) == pytest.approx(1.0)
    assert float(spatial_correlation(-truth, truth)) == pytest.approx(-1.0)
    flat = torch.full((2, 3, 10), 0.4, requires_grad=True)  # a constant prediction: correlation 0, finite gradient
    out = spatial_correlation(flat, torch.rand(2, 3, 10, generator=g))
    out.backward()
    assert float(out) == pytest.approx(0.0, abs=1e-6) and torch.isfinite(flat.grad).all()
    assert float(spatial_correlation(flat, torch.ones(2, 3, 10))) == 0.0  # every true frame constant


def test_cc_loss_adds_its_weight_times_one_minus_cc(tiny_store, tiny_config, tmp_path):
    from learner.metrics import spatial_cc
    from learner.train.loss import episode_loss
    from shared.errors import ConfigError

    model, ep, hier = _model_and_episode(tiny_store, tiny_config, tmp_path / "run")
    with torch.no_grad():  # a fresh model predicts the mean everywhere: perturb it so that its maps vary
        for p in model.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))

    def terms(weight: float):
        return episode_loss(model, ep, hier, 0.3, 0.7, generator=torch.Generator().manual_seed(0), cc_weight=weight)

    with_cc, without = terms(0.2), terms(0.0)
    torch.testing.assert_close(with_cc.total - without.total, 0.2 * (1 - with_cc.spatial_cc))
    assert float(without.spatial_cc) == 0.0
    with torch.no_grad():
        c = model.embed_prior_and_posterior(ep.context_obs, ep.target_u * ep.observed, ep.observed, hier)[1]
        pred = model.generate(
            torch.cat([ep.context_sites, ep.target_sites]), hier, c.sample(torch.Generator().manual_seed(0))
        )
    truth = torch.cat([ep.context_u, ep.target_u])
    assert float(with_cc.spatial_cc) == pytest.approx(spatial_cc(pred.numpy(), truth.numpy()), abs=1e-5)
    with pytest.raises(ConfigError, match="cc_loss must be >= 0"):
        tiny_config(tiny_store, tmp_path / "run", cc_loss=-0.1)
