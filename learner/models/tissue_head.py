"""What ``c`` says about the tissue: a per-node abnormal-tissue logit and the healthy conduction velocity.

The head reads a draw of ``c`` (``(V, latent)`` on the coarsest graph)::

    logit_n  = G_t(c)_n                              graph decoder, one value per mesh node
    log cv   = log CV_0 + h(mean_v c_v, log l)        an MLP on the pooled c and the working graph's edge length

``logit_n`` is the log-odds that node ``n`` is scar core or border zone
(:data:`shared.tissue.ABNORMAL_LABELS`); ``cv`` the healthy tissue's conduction
velocity in m/s. The mean edge length ``l`` (mm) of the working graph gives the
head the mesh's scale, which the graph convolutions do not see: the same
activation sequence on a heart twice as large conducts twice as fast.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import MeshHierarchy
from learner.models.graph_decoder import GraphDecoder

__all__ = ["TissueHead", "DEFAULT_CV", "mean_edge_length"]

#: The conduction velocity (m/s) the head starts from: that of the default healthy tissue.
DEFAULT_CV = 1.085


def mean_edge_length(hierarchy: MeshHierarchy) -> Tensor:
    """Mean edge length (mesh units, mm) of the working graph (level 0 of ``hierarchy``)."""
    graph = hierarchy.graphs[0]
    src, dst = graph.edge_index
    return (graph.positions[src] - graph.positions[dst]).norm(dim=-1).mean()


class TissueHead(nn.Module):
    """``c`` ``(V, latent)`` to abnormal-tissue logits ``(N,)`` on the mesh's nodes and ``log cv`` ``()``."""

    def __init__(self, latent: int, channels: tuple[int, ...], hidden: int) -> None:
        super().__init__()
        self.decoder = GraphDecoder(latent, channels, hidden)
        self.speed = nn.Sequential(nn.Linear(latent + 1, hidden), nn.ELU(), nn.Linear(hidden, 1))
        nn.init.zeros_(self.speed[-1].weight)  # starts at DEFAULT_CV everywhere
        nn.init.zeros_(self.speed[-1].bias)
        nn.init.constant_(self.decoder.out.bias, -2.0)  # starts at an abnormal share of 12 %

    def forward(self, c: Tensor, hierarchy: MeshHierarchy) -> tuple[Tensor, Tensor]:
        logit = hierarchy.to_mesh(self.decoder(c.unsqueeze(0), hierarchy)).squeeze(0)
        scale = torch.log(mean_edge_length(hierarchy)).to(c).reshape(1)
        log_cv = math.log(DEFAULT_CV) + self.speed(torch.cat([c.mean(dim=0), scale])).squeeze(-1)
        return logit, log_cv
