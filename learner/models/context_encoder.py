"""The meta-model q(c | Y): feed-forward embedding of a set of observed sequences."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import MeshHierarchy
from learner.models.graph_encoder import GraphEncoder
from learner.nn.gcn_gru import GCNGRU

__all__ = ["ContextEncoder"]

#: Initial log-variance of q(c | Y): draws of ``c`` start with a spread of 0.14, below that of the means
#: across subjects (~0.4). With the default 0 the draws were mostly noise, the generator learned to ignore ``c``,
#: and training sat at the accuracy of PNS for tens of epochs (docs/training.md).
INITIAL_LOGVAR = -4.0


class ContextEncoder(nn.Module):
    r"""Observed sequences ``(K, T, N_0)`` on nodes ``observed`` to :math:`(\mu_c, \log\sigma^2_c)`.

    Each sequence passes the graph encoder (inputs: the observed values, zero
    elsewhere, and the observation mask: the observed nodes ``(N,)``, or per
    value ``(K, T, N)`` where a recording fixes only some frames of a node, as
    an activation-time map does), a GCN-GRU over time on the coarsest
    graph and a linear layer compressing time; the embeddings are averaged over
    the set, and two linear layers give the mean and log-variance of ``c``
    (``latent`` channels per coarse node). Averaging makes the embedding
    independent of the order and (in form) of the size of the set.
    """

    def __init__(self, frames: int, channels: tuple[int, ...], hidden: int, latent: int, stride: int = 1) -> None:
        super().__init__()
        self.frames, self.stride = frames, stride
        self.encoder = GraphEncoder(2, channels, hidden, latent)
        self.gru = GCNGRU(latent, latent)
        self.compress_time = nn.Linear(len(range(0, frames, stride)), 1)
        self.mu = nn.Linear(latent, latent)
        self.logvar = nn.Linear(latent, latent)
        nn.init.constant_(self.logvar.bias, INITIAL_LOGVAR)

    def embed_sequences(self, obs: Tensor, observed: Tensor, hierarchy: MeshHierarchy) -> Tensor:
        """Per-sequence embeddings ``h(y_1:T)``: ``(K, V, latent)`` (before the set average).

        Every ``stride``-th frame is encoded: the graph encoder runs once per
        encoded frame, which dominates the cost of a training episode.
        """
        if obs.shape[1] != self.frames:
            raise ValueError(f"context sequences have {obs.shape[1]} frames, the model was built for {self.frames}")
        if observed.dim() == 3:
            observed = observed[:, :: self.stride]
        obs, observed = hierarchy.level0_observations(obs[:, :: self.stride], observed)
        k, t, n = obs.shape
        mask = observed.to(obs.dtype).expand(k, t, n)
        x = torch.stack([obs * mask, mask], dim=-1).reshape(k * t, n, 2)
        e = self.encoder(x, hierarchy)  # (K*T, V, L)
        h = self.gru(e.reshape(k, t, *e.shape[1:]), hierarchy.graphs[-1])  # (K, T, V, L)
        return self.compress_time(h.permute(0, 2, 3, 1)).squeeze(-1)

    def distribution(self, embeddings: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and log-variance of ``c`` from the set average of per-sequence embeddings."""
        pooled = embeddings.mean(dim=0)
        return self.mu(pooled), self.logvar(pooled).clamp(-10.0, 10.0)

    def forward(self, obs: Tensor, observed: Tensor, hierarchy: MeshHierarchy) -> tuple[Tensor, Tensor]:
        return self.distribution(self.embed_sequences(obs, observed, hierarchy))
