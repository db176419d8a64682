"""Refining c on the context set: the objective it minimises, what it leaves alone, bad settings."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.config import ModelConfig
from learner.data.episodes import load_episode
from learner.evaluate import NeuralMethod
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS
from learner.refine import Refinement, fit_context, observed_nodes, recorded_values, refine_context
from learner.store_view import StoreView
from shared.errors import InputError

CONFIG = ModelConfig(channels=(4, 8), hidden=16, latent=8, levels=3, coarsest=10, coarse_blocks=1)


@pytest.fixture(scope="module")
def setup(tiny_store, trained_like):
    view = StoreView(tiny_store)
    hier = view.hierarchy("lv", CONFIG.levels, CONFIG.coarsest)
    episode = load_episode(tiny_store, "lv-scar-apex", [0, 5], [1, 2, 3], "surface")
    torch.manual_seed(0)
    model = trained_like(MetaPNS(CONFIG, view.frames).eval())
    return view, hier, episode, model


def _refine(setup, refinement: Refinement):
    view, hier, ep, model = setup
    post = model.embed(ep.context_obs, ep.observed, hier)
    target, record = ep.context_obs[..., ep.observed], observed_nodes(ep.observed)
    c, history, taken = refine_context(
        model, post, target, record, ep.context_sites, hier, SiteEvidence.of(ep), refinement
    )
    return post, c, history, taken


def _fit(setup, post, refinement: Refinement, steps: int, keep=None, held_out=None):
    """:func:`fit_context` on the context recordings ``keep`` (default all), checked on ``held_out``."""
    view, hier, ep, model = setup
    m = ep.observed.bool()
    target = ep.context_obs[..., m]
    keep = slice(None) if keep is None else keep
    check = None if held_out is None else (ep.context_sites[held_out], target[held_out])
    mu, var = post.mu.detach(), post.logvar.detach().exp()
    fit = (ep.context_sites[keep], target[keep])
    return fit_context(model, mu, var, fit, hier, SiteEvidence.of(ep), observed_nodes(m), refinement, steps, check)


def _negative_log_posterior(setup, post, c, sigma: float) -> float:
    """The documented objective, written out directly."""
    view, hier, ep, model = setup
    with torch.no_grad():
        pred = model.generate(ep.context_sites, hier, c).numpy()
    m = ep.observed.numpy()
    residual = pred[..., m] - ep.context_obs.numpy()[..., m]
    mu, var = post.mu.detach().numpy(), post.logvar.detach().exp().numpy()
    return 0.5 * float((residual**2).sum()) / sigma**2 + 0.5 * float(((c.numpy() - mu) ** 2 / var).sum())


def test_values_a_recording_does_not_fix_add_nothing_to_the_objective(setup):
    view, hier, ep, model = setup
    m = ep.observed.bool()
    recorded = m.expand_as(ep.context_obs).clone()
    recorded[:, 10:] = False  # an activation map fixes the first frames only
    target = recorded_values(ep.context_obs, m, recorded)
    assert target.shape == (2, view.frames, int(m.sum())) and target[:, 10:].isnan().all()
    assert torch.equal(target[:, :10], ep.context_obs[:, :10][..., m])
    post = model.embed(ep.context_obs, recorded, hier)
    mu, var = post.mu.detach(), post.logvar.detach().exp()
    refinement = Refinement(steps=3)
    fit = (ep.context_sites, target)
    c, history, checked = fit_context(
        model, mu, var, fit, hier, SiteEvidence.of(ep), observed_nodes(m), refinement, 3, fit
    )
    assert np.isfinite(history).all() and np.isfinite(checked).all()
    with torch.no_grad():
        pred = model.generate(ep.context_sites, hier, mu)[..., m]
    residual = (pred - ep.context_obs[..., m])[:, :10]
    assert history[0] == pytest.approx(0.5 * float(residual.pow(2).sum()) / 0.2**2, rel=1e-4)  # c = mu: no prior term
    assert checked[0] == pytest.approx(float(residual.pow(2).mean()), rel=1e-4)


def test_no_steps_keeps_the_encoders_mean(setup):
    post, c, history, taken = _refine(setup, Refinement(steps=0))
    assert torch.equal(c, post.mu.detach()) and history == [] and taken == 0


def test_steps_lower_the_negative_log_posterior_as_documented(setup):
    refinement = Refinement(steps=15, lr=0.05, sigma=0.2)
    post = setup[3].embed(setup[2].context_obs, setup[2].observed, setup[1])
    c, history, _ = _fit(setup, post, refinement, 15)
    assert len(history) == 16
    assert history[-1] < 0.9 * history[0]
    assert not torch.equal(c, post.mu.detach())
    # the reported objective is the formula of the docstring, at the start and at the returned c
    assert history[0] == pytest.approx(_negative_log_posterior(setup, post, post.mu.detach(), 0.2), rel=1e-4)
    assert history[-1] == pytest.approx(_negative_log_posterior(setup, post, c, 0.2), rel=1e-4)


def test_the_step_count_is_chosen_on_recordings_held_out_in_turn(setup):
    refinement = Refinement(steps=12, lr=0.2, sigma=0.2)
    post, c, history, taken = _refine(setup, refinement)
    k = len(setup[2].context_sites)
    curves = [_fit(setup, post, refinement, 12, torch.arange(k) != left, slice(left, left + 1))[2] for left in range(k)]
    assert all(len(curve) == 13 for curve in curves)
    assert taken == int(np.argmin(np.mean(curves, axis=0)))
    if taken:
        expected, objective, _ = _fit(setup, post, refinement, taken)
        assert torch.allclose(c, expected) and history == pytest.approx(objective)
    else:
        assert torch.equal(c, post.mu.detach()) and history == []


def test_a_single_recording_is_not_refined(setup):
    view, hier, ep, model = setup
    post = model.embed(ep.context_obs[:1], ep.observed, hier)
    target, record = ep.context_obs[:1, :, ep.observed], observed_nodes(ep.observed)
    c, history, taken = refine_context(
        model, post, target, record, ep.context_sites[:1], hier, None, Refinement(steps=10)
    )
    assert torch.equal(c, post.mu.detach()) and history == [] and taken == 0


def test_a_large_sigma_keeps_c_near_the_encoders_mean(setup):
    post = setup[3].embed(setup[2].context_obs, setup[2].observed, setup[1])
    tight = _fit(setup, post, Refinement(steps=10, sigma=0.05), 10)[0]
    loose = _fit(setup, post, Refinement(steps=10, sigma=50.0), 10)[0]
    mu = post.mu.detach()
    assert (loose - mu).norm() < (tight - mu).norm()


def test_refinement_leaves_the_weights_alone(setup):
    model = setup[3]
    before = {k: v.clone() for k, v in model.state_dict().items()}
    _refine(setup, Refinement(steps=3))
    for name, value in model.state_dict().items():
        assert torch.equal(value, before[name]), name
    assert all(p.grad is None for p in model.parameters())


def test_a_refined_method_predicts_with_the_refined_c(setup):
    view, hier, ep, model = setup
    refinement = Refinement(steps=12, lr=0.2)
    _, c, _, _ = _refine(setup, refinement)
    method = NeuralMethod(model, "m", refine=refinement)
    method.fit(ep, view.mesh("lv"), hier)
    with torch.no_grad():
        expected = model.generate(ep.target_sites, hier, c, evidence=SiteEvidence.of(ep)).numpy()
    np.testing.assert_allclose(method.predict(ep.target_sites), expected, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"steps": -1}, "steps"),
        ({"steps": 2.5}, "steps"),
        ({"steps": True}, "steps"),
        ({"lr": 0.0}, "lr"),
        ({"lr": float("nan")}, "lr"),
        ({"sigma": -1.0}, "sigma"),
        ({"sigma": float("inf")}, "sigma"),
    ],
)
def test_bad_settings_are_refused_by_name(kwargs, word):
    with pytest.raises(InputError, match=word):
        Refinement(**kwargs)
