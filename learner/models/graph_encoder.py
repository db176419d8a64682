"""Graph encoder: residual spline-conv blocks down the mesh hierarchy to per-coarse-node features."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import MeshHierarchy
from learner.nn.residual_block import ResidualGraphBlock

__all__ = ["GraphEncoder"]


class GraphEncoder(nn.Module):
    r"""Fine-mesh fields ``(B, N_0, C_in)`` to coarse latent features ``(B, N_L, latent)``.

    Block ``l`` convolves on level ``l`` and mean-pools to level ``l + 1``; two
    1x1 layers then map to the latent space, :math:`\tanh` bounded as in the
    reference model.
    """

    def __init__(self, in_channels: int, channels: tuple[int, ...], hidden: int, latent: int) -> None:
        super().__init__()
        widths = (in_channels, *channels)
        self.blocks = nn.ModuleList(ResidualGraphBlock(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.fc1 = nn.Linear(channels[-1], hidden)
        self.fc2 = nn.Linear(hidden, latent)

    def forward(self, x: Tensor, hierarchy: MeshHierarchy) -> Tensor:
        return self.forward_levels(x, hierarchy)[0]

    def forward_levels(self, x: Tensor, hierarchy: MeshHierarchy) -> tuple[Tensor, list[Tensor]]:
        """The latent features and each block's output on its own level (fine to coarse)."""
        levels = []
        for level, block in enumerate(self.blocks):
            x = block(x, hierarchy.graphs[level])
            levels.append(x)
            x = hierarchy.pool(x, level)
        return torch.tanh(self.fc2(nn.functional.elu(self.fc1(x)))), levels
