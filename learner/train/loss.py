r"""The episode loss (docs/method.md, "Training objective") (negative ELBO of the set-conditioned model).

.. math::

    \mathcal{L} = \mathrm{rec}(X_{target}) + \mathrm{rec}(X_{context})
      + \lambda_1 \mathrm{KL}(q(c \mid Y \cup X) \,\|\, p(c \mid Y))
      + \lambda_2 \mathrm{KL}(p(c \mid Y) \,\|\, \mathcal{N}(0, I))
      \; [+ \, w \, \mathrm{BCE}(g, \mathrm{wave})] \; [+ \, w_{cc} (1 - \mathrm{CC})]
      \; [+ \, w_t (\mathrm{BCE}(p, \mathrm{abnormal}) + (\log \hat{v} - \log v)^2)]

where ``rec`` is the squared error summed over nodes and frames and averaged
over sequences (a Gaussian log-likelihood up to constants), ``p(c | Y)`` is the
embedding of the context set and ``q(c | Y u X)`` that of context and targets
(both by the same network). An episode whose context is recorded as ECGs
(``Episode.context_ecg``) takes ``p(c | Y)`` from the ECG encoder instead; one
whose context is recorded as activation-time maps (``Episode.context_recorded``)
takes it from the maps encoder of a model that has one (``q(c | Y u X)`` as
ever).
PNS has no ``c``: its loss is the reconstruction.

With a capture gate and ``train.gate_loss`` ``w > 0`` the gate ``g`` of every
context and target site is also fitted, by binary cross-entropy, to whether
that site's stored simulation starts a wave (:func:`learner.metrics.wave_started`):
the reconstruction alone teaches the gate only once the decoder draws waves,
and only through the few sites whose stimulus starts none (docs/training.md).

With ``train.cc_loss`` ``w_cc > 0`` the loss also has ``1 - CC``, CC the mean
over decoded frames of every sequence of the Pearson correlation over nodes
between prediction and truth (:func:`spatial_correlation`, the evaluation's
``cc_spatial``). Its scale does not depend on a frame's spatial spread, so it
also weighs the nearly uniform frames of a fully excited heart, whose
variations of a few thousandths the squared error ignores (docs/anatomies.md).

With a tissue head and ``train.tissue_loss`` ``w_t > 0``, a draw of ``c`` from
``p(c | Y)`` (the context alone, as a personalised heart has it) is read by the
head (:meth:`~learner.models.surrogate.MetaPNS.tissue`): its abnormal-tissue
probability ``p`` is fitted to the subject's scar core and border nodes by the
cross-entropy averaged over nodes, its conduction velocity ``v-hat`` to the
healthy tissue's ``v`` by the squared log error (left out where the store's
cell model has no closed form, ``Episode.cv`` NaN).

The optimiser gets :math:`\mathcal{L} / (N T)` for a mesh of ``N`` nodes and
``T`` frames: mean squared errors plus KL terms weighted by
:math:`\lambda_i / (N T)`. That is the same objective, episode by episode, with
gradients of order one instead of ~1e5, so that ``train.grad_clip`` is a bound
on outliers (measured in docs/training.md) rather than a rescaling of every step.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.nn.functional import binary_cross_entropy_with_logits

from learner.data.episodes import Episode
from learner.graph.hierarchy import MeshHierarchy
from learner.metrics import wave_started
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import PNS, MetaPNS, Posterior

__all__ = [
    "LossTerms",
    "gaussian_kl",
    "standard_normal_kl",
    "spatial_correlation",
    "episode_loss",
    "tissue_terms",
    "EpisodeObjective",
]


@dataclass
class LossTerms:
    """The loss and its parts: ``total`` is what the optimiser gets (the negative ELBO per node and frame, plus the
    weighted gate cross-entropy and correlation terms); the MSEs, KLs, ``gate_bce`` (0 without a gate loss) and
    ``spatial_cc`` (0 without a correlation loss), ``tissue_bce`` and ``cv_log_error`` (the squared log error of the
    conduction velocity; both 0 without a tissue loss) as defined above."""

    total: Tensor
    target_mse: Tensor
    context_mse: Tensor
    kl_posterior: Tensor
    kl_prior: Tensor
    gate_bce: Tensor
    spatial_cc: Tensor
    tissue_bce: Tensor
    cv_log_error: Tensor

    def as_floats(self) -> dict[str, float]:
        """Detached values for logging."""
        return {k: float(v.detach()) for k, v in vars(self).items()}


def gaussian_kl(q: Posterior, p: Posterior) -> Tensor:
    """KL(q || p) of diagonal Gaussians, summed over every dimension."""
    var_ratio = torch.exp(q.logvar - p.logvar)
    return 0.5 * torch.sum(var_ratio + (q.mu - p.mu) ** 2 / torch.exp(p.logvar) - 1.0 - (q.logvar - p.logvar))


def standard_normal_kl(p: Posterior) -> Tensor:
    """KL(p || N(0, I)), summed over every dimension."""
    return 0.5 * torch.sum(torch.exp(p.logvar) + p.mu**2 - 1.0 - p.logvar)


def spatial_correlation(pred: Tensor, truth: Tensor, eps: float = 1e-12) -> Tensor:
    """Pearson correlation over the last axis (nodes), averaged over the frames whose truth is not constant.

    Differentiable :func:`learner.metrics.spatial_cc`; a constant predicted frame
    counts as correlation 0 (``eps`` keeps its gradient finite). 0 when every
    true frame is constant.
    """
    p = pred - pred.mean(-1, keepdim=True)
    t = truth - truth.mean(-1, keepdim=True)
    t_var = (t * t).sum(-1)
    cc = (p * t).sum(-1) / torch.sqrt((p * p).sum(-1) * t_var + eps)
    varying = truth.amax(-1) > truth.amin(-1)  # exactly, as the metric: centring leaves rounding residue
    return cc[varying].mean() if bool(varying.any()) else torch.zeros((), device=pred.device)


def episode_loss(
    model: PNS,
    episode: Episode,
    hierarchy: MeshHierarchy,
    lambda1: float,
    lambda2: float,
    kl_weight: float = 1.0,
    frames: Tensor | None = None,
    generator: torch.Generator | None = None,
    posterior_targets: int | None = None,
    c_from: str = "posterior",
    gate_weight: float = 0.0,
    cc_weight: float = 0.0,
    reconstruction: bool = True,
    tissue_weight: float = 0.0,
) -> LossTerms:
    """Loss of one episode; ``frames`` restricts the reconstruction to a subset of frame indices.

    The reconstruction is a mean over the decoded frames times ``N T``: with a
    frame subset, an unbiased estimate of the full sum that decodes fewer
    frames. ``posterior_targets`` caps how many targets join the context in
    q(c | Y u X) (None: all), since encoding a sequence costs more than
    decoding a frame. ``c_from`` is the distribution the generator's ``c`` is
    drawn from: ``"posterior"`` q(c | Y u X), or ``"context"`` p(c | Y), the
    embedding a trained model is given at test time. ``gate_weight`` is the
    weight ``w`` of the capture gate's cross-entropy (a model without a gate
    with ``w > 0`` is an error); ``cc_weight`` that of ``1 - CC``;
    ``tissue_weight`` that of the tissue head's terms. Without
    ``reconstruction`` the loss is the KL terms alone (the MSEs are reported as
    0): an encoder trained beside a frozen model then learns to match its
    posterior, at the cost of the encoders only.
    """
    sites = torch.cat([episode.context_sites, episode.target_sites])
    truth = torch.cat([episode.context_u, episode.target_u])
    zero = torch.zeros((), device=truth.device)
    c, evidence, kl_q, kl_p, prior = None, None, zero, zero, None
    if model.conditioned:
        # the context only: a target's own sequence would give its answer away; an ECG shows no site's own values
        evidence = SiteEvidence.of(episode) if episode.context_ecg is None else None
        extra = episode.target_u[:posterior_targets] * episode.observed.to(truth.dtype)
        prior, posterior = model.embed_prior_and_posterior(episode.context_obs, extra, episode.observed, hierarchy)
        if episode.context_ecg is not None:  # p(c | Y) from the ECGs of the context; q(c | Y u X) as ever
            prior = model.embed_ecg(episode.context_ecg, episode.lead_field, episode.context_sites, hierarchy)
        elif episode.context_recorded is not None and model.maps_encoder is not None:  # p(c | Y) from the maps
            prior = model.embed(episode.context_obs, episode.observed, hierarchy, episode.context_recorded)
        c = (prior if c_from == "context" else posterior).sample(generator)
        kl_q, kl_p = gaussian_kl(posterior, prior), standard_normal_kl(prior)
    tissue_bce, cv_error = zero, zero
    if tissue_weight > 0:
        if prior is None:
            raise ValueError("train.tissue_loss fits the tissue head of a metaPNS: this model has no c")
        tissue_bce, cv_error = tissue_terms(model, prior.sample(generator), episode, hierarchy)
    tissue = tissue_weight * (tissue_bce + cv_error)
    if not reconstruction:  # the embedding terms alone: the generator is not run
        per_value = 1.0 / (truth.shape[-1] * model.frames)
        total = kl_weight * per_value * (lambda1 * kl_q + lambda2 * kl_p) + tissue
        return LossTerms(total, zero, zero, kl_q, kl_p, zero, zero, tissue_bce, cv_error)
    pred, logit = model.generate_with_gate(sites, hierarchy, c, frames, evidence)
    gate_bce = zero
    if gate_weight > 0:
        if logit is None:
            raise ValueError("train.gate_loss fits the capture gate: this model has none (model.capture_gate)")
        waves = torch.from_numpy(wave_started(truth.detach().cpu().numpy())).to(logit)
        gate_bce = binary_cross_entropy_with_logits(logit, waves)
    if frames is not None:
        truth = truth[:, frames]
    err = (pred - truth) ** 2
    k = len(episode.context_sites)
    n_frames, n_nodes = model.frames, truth.shape[-1]
    per_value = 1.0 / (n_nodes * n_frames)
    target_mse, context_mse = err[k:].mean(), err[:k].mean()
    total = target_mse + context_mse + kl_weight * per_value * (lambda1 * kl_q + lambda2 * kl_p)
    cc = spatial_correlation(pred, truth) if cc_weight > 0 else zero
    total = total + gate_weight * gate_bce + (cc_weight * (1 - cc) if cc_weight > 0 else zero) + tissue
    return LossTerms(total, target_mse, context_mse, kl_q, kl_p, gate_bce, cc, tissue_bce, cv_error)


def tissue_terms(model: PNS, c: Tensor, episode: Episode, hierarchy: MeshHierarchy) -> tuple[Tensor, Tensor]:
    """The tissue head's cross-entropy against the episode's abnormal nodes and its squared log-CV error (0 where
    the episode's ``cv`` is NaN) for the draw ``c``."""
    if not isinstance(model, MetaPNS) or model.tissue_head is None:
        raise ValueError("train.tissue_loss fits the tissue head: this model has none (model.tissue_head)")
    if episode.abnormal is None or episode.cv is None:
        raise ValueError(f"episode of {episode.subject_id!r} carries no tissue truth (Episode.abnormal, Episode.cv)")
    logit, log_cv = model.tissue(c, hierarchy)
    bce = binary_cross_entropy_with_logits(logit, episode.abnormal.to(logit))
    cv = episode.cv.to(log_cv)
    error = (log_cv - torch.log(cv)) ** 2 if bool(torch.isfinite(cv)) else torch.zeros_like(log_cv)
    return bce, error


class EpisodeObjective(nn.Module):
    """:func:`episode_loss` as a module's ``forward``, the call that ``DistributedDataParallel`` wraps."""

    def __init__(
        self,
        model: PNS,
        lambda1: float,
        lambda2: float,
        posterior_targets: int | None = None,
        c_from: str = "posterior",
        gate_weight: float = 0.0,
        cc_weight: float = 0.0,
        reconstruction: bool = True,
        tissue_weight: float = 0.0,
    ) -> None:
        super().__init__()
        self.model, self.lambda1, self.lambda2 = model, lambda1, lambda2
        self.posterior_targets, self.c_from = posterior_targets, c_from
        self.gate_weight, self.cc_weight, self.reconstruction = gate_weight, cc_weight, reconstruction
        self.tissue_weight = tissue_weight

    def forward(
        self,
        episode: Episode,
        hierarchy: MeshHierarchy,
        kl_weight: float,
        frames: Tensor | None,
        generator: torch.Generator | None,
    ) -> LossTerms:
        return episode_loss(
            self.model,
            episode,
            hierarchy,
            self.lambda1,
            self.lambda2,
            kl_weight,
            frames,
            generator,
            self.posterior_targets,
            self.c_from,
            self.gate_weight,
            self.cc_weight,
            self.reconstruction,
            self.tissue_weight,
        )
