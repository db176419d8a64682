"""Shapes, gradients and invariances of the metaPNS / PNS networks."""

from __future__ import annotations

import pytest
import torch

from learner.config import ModelConfig
from learner.data.episodes import load_episode
from learner.models.surrogate import PNS, MetaPNS, build_model
from learner.store_view import StoreView
from learner.train.loss import episode_loss

CONFIG = ModelConfig(channels=(4, 8), hidden=16, latent=8, levels=3, coarsest=10, coarse_blocks=1)


@pytest.fixture(scope="module")
def setup(tiny_store):
    view = StoreView(tiny_store)
    hier = view.hierarchy("lv", CONFIG.levels, CONFIG.coarsest)
    episode = load_episode(tiny_store, "lv-scar-apex", [0, 5], [1, 2, 3], "surface")
    return view, hier, episode


@pytest.mark.parametrize("skips", [False, True])
def test_generate_and_embed_shapes(setup, skips, trained_like):
    view, hier, ep = setup
    torch.manual_seed(0)
    model = trained_like(MetaPNS(ModelConfig(**{**CONFIG.__dict__, "decoder_skips": skips}), view.frames))
    n, v = hier.graphs[0].num_nodes, hier.graphs[-1].num_nodes
    post = model.embed(ep.context_obs, ep.observed, hier)
    assert post.mu.shape == post.logvar.shape == (v, CONFIG.latent)
    out = model.generate(ep.target_sites, hier, post.mu)
    assert out.shape == (3, view.frames, n)
    sub = model.generate(ep.target_sites, hier, post.mu, frames=torch.tensor([0, 4]))
    assert torch.allclose(sub, out[:, [0, 4]], atol=1e-6)


@pytest.mark.parametrize(
    "kind, extra",
    [
        ("metapns", {}),
        ("pns", {}),
        ("metapns", {"decoder_skips": True}),
        ("metapns", {"context_stimulus": True}),
        ("metapns", {"capture_gate": True}),
        ("metapns", {"capture_gate": True, "capture_evidence": True}),
    ],
)
def test_every_parameter_gets_a_finite_gradient(setup, kind, extra, trained_like):
    view, hier, ep = setup
    torch.manual_seed(0)
    config = ModelConfig(**{**CONFIG.__dict__, "kind": kind, **extra})
    model = trained_like(build_model(config, view.frames))
    if model.capture is not None:
        with torch.no_grad():  # a trained gate's output layer, so that its first layer gets a gradient too
            model.capture[-1].weight.normal_(0.0, 0.5)
    assert isinstance(model, MetaPNS) == (kind == "metapns")
    terms = episode_loss(model, ep, hier, lambda1=1e-4, lambda2=0.1, generator=torch.Generator().manual_seed(0))
    terms.total.backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, f"{name} gets no gradient"
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, f"{name}'s gradient is zero"
    if kind == "pns":
        assert float(terms.kl_posterior) == float(terms.kl_prior) == 0.0
        assert not hasattr(model, "context_encoder")


def test_context_embedding_ignores_the_order_of_the_set(setup):
    view, hier, ep = setup
    torch.manual_seed(0)
    model = MetaPNS(CONFIG, view.frames).eval()
    a = model.embed(ep.context_obs, ep.observed, hier)
    b = model.embed(ep.context_obs.flip(0), ep.observed, hier)
    assert torch.allclose(a.mu, b.mu, atol=1e-6) and torch.allclose(a.logvar, b.logvar, atol=1e-6)


def test_unobserved_values_do_not_reach_the_embedding(setup):
    view, hier, ep = setup
    model = MetaPNS(CONFIG, view.frames).eval()
    noisy = ep.context_obs.clone()
    noisy[:, :, ~ep.observed] = 123.0
    assert torch.equal(model.embed(noisy, ep.observed, hier).mu, model.embed(ep.context_obs, ep.observed, hier).mu)


@pytest.mark.parametrize("stride", [1, 3])
def test_a_mask_per_value_reads_only_the_recorded_values(setup, stride):
    view, hier, ep = setup
    torch.manual_seed(0)
    model = MetaPNS(CONFIG.__class__(**{**CONFIG.__dict__, "context_stride": stride}), view.frames).eval()
    every = ep.observed.expand_as(ep.context_obs)
    node_mask = model.embed(ep.context_obs, ep.observed, hier)
    torch.testing.assert_close(model.embed(ep.context_obs, every, hier).mu, node_mask.mu)
    recorded = every.clone()
    recorded[:, 6:] = False  # an activation map fixes the early frames only
    noisy = ep.context_obs.clone()
    noisy[:, 6:] = 123.0
    partial = model.embed(ep.context_obs, recorded, hier)
    assert torch.equal(model.embed(noisy, recorded, hier).mu, partial.mu)
    assert not torch.allclose(partial.mu, node_mask.mu)


def test_maps_reach_the_maps_encoder_through_their_mask_and_no_other_encoder(setup):
    view, hier, ep = setup
    torch.manual_seed(0)
    plain = MetaPNS(CONFIG, view.frames).eval()
    model = MetaPNS(CONFIG.__class__(**{**CONFIG.__dict__, "maps_encoder": True}), view.frames).eval()
    model.load_state_dict(plain.state_dict(), strict=False)
    recorded = ep.observed.expand_as(ep.context_obs).clone()
    recorded[:, 6:] = False
    maps = model.maps_encoder(ep.context_obs, recorded, hier)[0]
    context = model.context_encoder(ep.context_obs, ep.observed, hier)[0]
    assert torch.equal(model.embed(ep.context_obs, ep.observed, hier, recorded).mu, maps)
    assert torch.equal(model.embed(ep.context_obs, ep.observed, hier).mu, context)  # potentials: the context encoder
    assert torch.equal(plain.embed(ep.context_obs, ep.observed, hier, recorded).mu, context)  # every frame, as trained


def test_frame_count_mismatch_is_refused(setup):
    view, hier, ep = setup
    model = MetaPNS(CONFIG, view.frames + 1)
    with pytest.raises(ValueError, match="frames"):
        model.embed(ep.context_obs, ep.observed, hier)


def test_reference_size_model_is_near_one_million_parameters():
    n = sum(p.numel() for p in MetaPNS(ModelConfig(), 55).parameters())
    assert 2e5 < n < 3e6, n
    assert sum(p.numel() for p in PNS(ModelConfig(), 55).parameters()) < n


def test_context_stride_encodes_every_kth_frame(setup):
    view, hier, ep = setup
    torch.manual_seed(0)
    cfg = ModelConfig(**{**CONFIG.__dict__, "context_stride": 3})
    model = MetaPNS(cfg, view.frames).eval()
    assert model.context_encoder.compress_time.in_features == len(range(0, view.frames, 3))
    changed = ep.context_obs.clone()
    changed[:, 1] += 1.0  # frame 1 is skipped with stride 3
    assert torch.equal(model.embed(changed, ep.observed, hier).mu, model.embed(ep.context_obs, ep.observed, hier).mu)
    changed[:, 3] += 1.0  # frame 3 is encoded
    assert not torch.equal(
        model.embed(changed, ep.observed, hier).mu, model.embed(ep.context_obs, ep.observed, hier).mu
    )


def test_inference_layout_gives_the_training_paths_result(setup, trained_like):
    """Under no_grad the blocks, pooling and output layer run on the (N, C, B) layout: same sequences."""
    view, hier, ep = setup
    torch.manual_seed(0)
    model = trained_like(MetaPNS(CONFIG, view.frames)).eval()
    c = model.embed(ep.context_obs, ep.observed, hier).mu.detach()
    with torch.no_grad():
        fast = model.generate(ep.target_sites, hier, c)
        assert fast.std() > 1e-3  # not the constant output of a fresh decoder
        fast_c = model.embed(ep.context_obs, ep.observed, hier).mu
    slow = model.generate(ep.target_sites, hier, c).detach()
    torch.testing.assert_close(fast, slow, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(fast_c, c, rtol=1e-5, atol=1e-5)


def test_context_stimulus_starts_switched_off_and_then_conditions_z0(setup):
    """A fresh ``context_stimulus`` map is zero (the model without it); once trained, c changes z_0 at every node."""
    view, hier, ep = setup
    torch.manual_seed(0)
    model = MetaPNS(ModelConfig(**{**CONFIG.__dict__, "context_stimulus": True}), view.frames)
    c1 = model.embed(ep.context_obs, ep.observed, hier).mu
    c2 = c1 + torch.randn(c1.shape, generator=torch.Generator().manual_seed(1))
    sites = ep.target_sites
    fresh = model.initial(sites, hier, c1)
    assert torch.equal(fresh, model.initial(sites, hier, c2))
    assert torch.equal(fresh, model.initial(sites, hier))  # c given or not
    with torch.no_grad():
        model.context_stimulus.weight.normal_(0.0, 0.5)
    moved = (model.initial(sites, hier, c1) - model.initial(sites, hier, c2)).abs().amax(dim=-1)
    assert bool((moved > 0).all())
    assert PNS(ModelConfig(**{**CONFIG.__dict__, "context_stimulus": True}), view.frames).context_stimulus is None


def test_capture_gate_reads_c_only_at_the_site_and_closes_to_the_no_wave_response(setup, trained_like):
    """The gate starts at sigmoid(2) for every site, moves with c at the site's coarse node only, and at 0
    predicts the no-capture response r_t at every node."""
    view, hier, ep = setup
    torch.manual_seed(0)
    model = trained_like(MetaPNS(ModelConfig(**{**CONFIG.__dict__, "capture_gate": True}), view.frames))
    sites = ep.target_sites
    c = model.embed(ep.context_obs, ep.observed, hier).mu.detach()
    fresh = model.capture_probability(sites, hier, c)
    torch.testing.assert_close(fresh, torch.full((len(sites),), torch.sigmoid(torch.tensor(2.0)).item()))
    with torch.no_grad():
        model.capture[-1].weight.normal_(0.0, 0.5)
    gate = model.capture_probability(sites, hier, c)
    clusters = hier.coarsest_cluster(sites.long())
    elsewhere = torch.ones(hier.graphs[-1].num_nodes, dtype=torch.bool)
    elsewhere[clusters] = False
    c_far = c.clone()
    c_far[elsewhere] += 3.0
    torch.testing.assert_close(model.capture_probability(sites, hier, c_far), gate)
    c_site = c.clone()
    c_site[clusters[0]] += 3.0
    with torch.no_grad():
        assert float((model.capture_probability(sites, hier, c_site)[0] - gate[0]).abs()) > 1e-4
        model.capture[-1].bias.fill_(-60.0)
        model.no_capture.copy_(torch.linspace(0.0, 1.0, view.frames))
        out = model.generate(sites, hier, c)
    expected = model.no_capture.view(1, -1, 1).expand_as(out)
    torch.testing.assert_close(out, expected)
    assert PNS(ModelConfig(**{**CONFIG.__dict__, "capture_gate": True}), view.frames).capture is None
