"""Refine a context embedding on its own context set: semi-amortised inference of ``c``.

The context encoder amortises inference: one forward pass maps a context set to
q(c | Y). On a heart unlike the training hearts that amortised guess can be
off, and the generator then fits even the context it was given poorly. A few
gradient steps on ``c`` alone (the weights stay fixed) move it to the
maximum a posteriori estimate of

    log p(Y | c) + log q(c | Y),  with p(Y | c) = N(Y; generate(c), sigma^2) at the observed nodes,

the amortised posterior acting as the prior that keeps ``c`` near the
encoder's answer (semi-amortised inference: Kim et al. 2018,
*Semi-Amortized Variational Autoencoders*; Marino et al. 2018, *Iterative
Amortized Inference*). ``steps`` is the knob that matters: every observed
value adds to the likelihood, so with thousands of them it outweighs the prior,
and a fixed, small number of steps is what keeps ``c`` from fitting the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from learner.graph.hierarchy import MeshHierarchy
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS, Posterior
from shared.errors import InputError

__all__ = ["Refinement", "refine_context"]


@dataclass(frozen=True)
class Refinement:
    """How to refine ``c``: Adam ``steps`` (0: the encoder's mean), learning rate ``lr``, residual std ``sigma``."""

    steps: int = 0
    lr: float = 0.05
    sigma: float = 0.2

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 0:
            raise InputError(f"refinement steps must be an integer >= 0, got {self.steps!r}")
        for name in ("lr", "sigma"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise InputError(f"refinement {name} must be a finite number > 0, got {value!r}")


def refine_context(
    model: MetaPNS,
    posterior: Posterior,
    obs: Tensor,
    observed: Tensor,
    sites: Tensor,
    hierarchy: MeshHierarchy,
    evidence: SiteEvidence | None,
    refinement: Refinement,
) -> tuple[Tensor, list[float]]:
    """The MAP ``c`` for context ``obs`` (K, T, N) stimulated at ``sites`` (K,), and the objective per step.

    Starts from ``posterior.mu`` and minimises the negative log posterior
    ``0.5 * sum(residual^2) / sigma^2 + 0.5 * sum((c - mu)^2 / var)`` over the
    observed nodes; only ``c`` moves. The objective list has ``steps + 1``
    entries, the last one at the returned ``c``.
    """
    mu, var = posterior.mu.detach(), posterior.logvar.detach().exp()
    mask = observed.bool()
    target = obs[..., mask]
    c = mu.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([c], lr=refinement.lr)

    def objective() -> Tensor:
        residual = model.generate(sites, hierarchy, c, evidence=evidence)[..., mask] - target
        return 0.5 * residual.pow(2).sum() / refinement.sigma**2 + 0.5 * ((c - mu).pow(2) / var).sum()

    history = []
    with torch.enable_grad():
        for _ in range(refinement.steps):
            loss = objective()
            history.append(float(loss.detach()))
            (c.grad,) = torch.autograd.grad(loss, [c])  # the weights get no gradient
            optimizer.step()
        with torch.no_grad():
            history.append(float(objective()))
    return c.detach(), history
