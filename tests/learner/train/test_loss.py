"""The KL terms against torch.distributions, and the frame-subset estimate of the reconstruction."""

from __future__ import annotations

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
