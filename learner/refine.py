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
Amortized Inference*). Every observed value adds to the likelihood, so with
thousands of them it outweighs the prior and ``c`` goes on to fit the noise
and the recorded sites at the expense of the others: ``steps`` is a maximum,
and the number taken is chosen by early stopping on recordings held out of the
context set in turn (:func:`refine_context`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from learner.ecg import LeadField
from learner.graph.hierarchy import MeshHierarchy
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS, Posterior
from shared.errors import InputError

__all__ = ["Refinement", "fit_context", "refine_context", "recorded_values", "observed_nodes", "ecg_leads"]

#: Most recordings left out in turn to choose the number of refinement steps (spread over the context set).
HELD_OUT = 3


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


#: How a generated sequence (S, T, N) is recorded: its observed nodes, or its ECG.
Recorder = Callable[[Tensor], Tensor]


def fit_context(
    model: MetaPNS,
    mu: Tensor,
    var: Tensor,
    fit: tuple[Tensor, Tensor],
    hierarchy: MeshHierarchy,
    evidence: SiteEvidence | None,
    record: Recorder,
    refinement: Refinement,
    steps: int,
    held_out: tuple[Tensor, Tensor] | None = None,
) -> tuple[Tensor, list[float], list[float]]:
    """Adam on ``c`` for ``steps`` steps on the recordings ``fit`` = (sites, recorded values), which ``record``
    makes of generated sequences: the final ``c``, the objective per step (``steps + 1`` entries) and, with
    ``held_out`` = (sites, values), the held-out recordings' mean squared residual at each of the same ``c``."""
    sites, target = fit
    c = mu.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([c], lr=refinement.lr)

    def objective() -> Tensor:
        residual = _residual(record(model.generate(sites, hierarchy, c, evidence=evidence)), target)
        return 0.5 * residual.pow(2).sum() / refinement.sigma**2 + 0.5 * ((c - mu).pow(2) / var).sum()

    def held_out_error() -> list[float]:
        if held_out is None:
            return []
        with torch.no_grad():
            generated = model.generate(held_out[0], hierarchy, c, evidence=evidence)
            return [float(_residual(record(generated), held_out[1]).pow(2).sum() / held_out[1].isfinite().sum())]

    history, checked = [], []
    with torch.enable_grad():
        for _ in range(steps):
            checked += held_out_error()
            loss = objective()
            history.append(float(loss.detach()))
            (c.grad,) = torch.autograd.grad(loss, [c])  # the weights get no gradient
            optimizer.step()
        with torch.no_grad():
            history.append(float(objective()))
        checked += held_out_error()
    return c.detach(), history, checked


def refine_context(
    model: MetaPNS,
    posterior: Posterior,
    target: Tensor,
    record: Recorder,
    sites: Tensor,
    hierarchy: MeshHierarchy,
    evidence: SiteEvidence | None,
    refinement: Refinement,
) -> tuple[Tensor, list[float], int]:
    """The MAP ``c`` for recordings ``target`` (K, ...) of pacings at ``sites`` (K,), which ``record`` makes
    of generated sequences (the observed nodes' values: :func:`observed_nodes`; ECGs: :func:`ecg_leads`), its
    objective per step, and the number of steps taken.

    Starts from ``posterior.mu`` and minimises the negative log posterior
    ``0.5 * sum(residual^2) / sigma^2 + 0.5 * sum((c - mu)^2 / var)`` over the
    recorded values (a NaN in ``target`` is a value not recorded,
    :func:`recorded_values`); only ``c`` moves. The number of steps is chosen
    on held-out recordings (early stopping): each of up to :data:`HELD_OUT` recordings in
    turn is left out, ``c`` is refined on the others for up to
    ``refinement.steps`` steps, and the step count with the smallest mean
    error on the left-out recordings is then run on all of them; 0 (the
    encoder's mean) where no step helps, and always with a single recording,
    which has nothing to check against. The objective list
    has ``taken + 1`` entries, the last one at the returned ``c``.
    """
    mu, var = posterior.mu.detach(), posterior.logvar.detach().exp()
    k = len(sites)
    if k < 2:
        return mu.clone(), [], 0
    curves = []
    for left in np.linspace(0, k - 1, min(k, HELD_OUT)).round().astype(int).tolist():
        keep = torch.arange(k, device=sites.device) != left
        _, _, checked = fit_context(
            model,
            mu,
            var,
            (sites[keep], target[keep.to(target.device)]),
            hierarchy,
            evidence,
            record,
            refinement,
            refinement.steps,
            (sites[left : left + 1], target[left : left + 1]),
        )
        curves.append(checked)
    taken = int(np.argmin(np.mean(curves, axis=0)))
    if taken == 0:
        return mu.clone(), [], 0
    c, history, _ = fit_context(model, mu, var, (sites, target), hierarchy, evidence, record, refinement, taken)
    return c, history, taken


def _residual(recorded: Tensor, target: Tensor) -> Tensor:
    """``recorded - target``, 0 where the target is NaN (a value the recording does not fix)."""
    return torch.where(target.isnan(), torch.zeros_like(recorded), recorded - target)


def recorded_values(obs: Tensor, observed: Tensor, recorded: Tensor | None = None) -> Tensor:
    """The target that :func:`observed_nodes` records: ``obs`` (K, T, N) at the ``observed`` nodes (N,), NaN
    where ``recorded`` (K, T, N), if given, is false (an activation-time map fixes no potential there)."""
    if recorded is not None:
        obs = torch.where(recorded.bool(), obs, torch.full_like(obs, float("nan")))
    return obs[..., observed.bool()]


def observed_nodes(observed: Tensor) -> Recorder:
    """Record generated sequences at the ``observed`` nodes (N,), as a potential recording is."""
    mask = observed.bool()
    return lambda u: u[..., mask]


def ecg_leads(lead_field: LeadField, scale: float) -> Recorder:
    """Record generated sequences as their 12-lead ECGs over ``scale`` (the recorded set's largest value)."""
    return lambda u: lead_field.ecg(u) / scale
