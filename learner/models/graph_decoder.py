"""Graph decoder (emission G): coarse latent states up the hierarchy to one value per mesh node."""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.functional import elu

from learner.graph.hierarchy import MeshHierarchy
from learner.nn.residual_block import ResidualGraphBlock

__all__ = ["GraphDecoder"]


class GraphDecoder(nn.Module):
    """Latent states ``(B, N_L, latent)`` to fields ``(B, N_0)``.

    Two 1x1 layers, then per level (coarse to fine) copy-unpooling and a
    residual graph block; a final 1x1 layer gives the transmembrane potential.
    With ``skips`` each block also sees the stimulus encoder's features of its
    level (a U-Net bridge): the coarse state says *when*, the bridge says
    *where* within a cluster the wavefront is.
    """

    def __init__(self, latent: int, channels: tuple[int, ...], hidden: int, skips: bool = False) -> None:
        super().__init__()
        self.fc1 = nn.Linear(latent, hidden)
        self.fc2 = nn.Linear(hidden, channels[-1])
        widths = tuple(reversed(channels)) + (channels[0],)
        extra = tuple(reversed(channels)) if skips else (0,) * len(channels)
        self.blocks = nn.ModuleList(ResidualGraphBlock(a + e, b) for a, b, e in zip(widths[:-1], widths[1:], extra))
        self.out = nn.Linear(channels[0], 1)
        nn.init.zeros_(self.out.weight)  # a fresh decoder predicts its bias everywhere (PNS.set_output_mean)

    def forward(self, z: Tensor, hierarchy: MeshHierarchy, skips: list[Tensor] | None = None) -> Tensor:
        """``skips[l]`` (B, N_l, C_l): features of level ``l`` joined to the decoder's input there."""
        x = elu(self.fc2(elu(self.fc1(z))))
        for i, block in enumerate(self.blocks):
            level = len(self.blocks) - 1 - i
            x = hierarchy.unpool(x, level)
            if skips is not None:
                x = torch.cat([x, skips[level]], dim=-1)
            x = block(x, hierarchy.graphs[level])
        cols = x.permute(1, 2, 0)
        if cols.is_contiguous():  # the (N, C, B) layout of an inference block: project it without a copy
            return (self.out.weight.view(-1) @ cols).T + self.out.bias
        return self.out(x).squeeze(-1)
