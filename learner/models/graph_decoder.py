"""Graph decoder (emission G): coarse latent states up the hierarchy to one value per mesh node."""

from __future__ import annotations

from torch import Tensor, nn
from torch.nn.functional import elu

from learner.graph.hierarchy import MeshHierarchy
from learner.nn.residual_block import ResidualGraphBlock

__all__ = ["GraphDecoder"]


class GraphDecoder(nn.Module):
    """Latent states ``(B, N_L, latent)`` to fields ``(B, N_0)``.

    Two 1x1 layers, then per level (coarse to fine) copy-unpooling and a
    residual graph block; a final 1x1 layer gives the transmembrane potential.
    """

    def __init__(self, latent: int, channels: tuple[int, ...], hidden: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(latent, hidden)
        self.fc2 = nn.Linear(hidden, channels[-1])
        widths = tuple(reversed(channels)) + (channels[0],)
        self.blocks = nn.ModuleList(ResidualGraphBlock(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.out = nn.Linear(channels[0], 1)

    def forward(self, z: Tensor, hierarchy: MeshHierarchy) -> Tensor:
        x = elu(self.fc2(elu(self.fc1(z))))
        for i, block in enumerate(self.blocks):
            level = len(self.blocks) - 1 - i
            x = block(hierarchy.unpool(x, level), hierarchy.graphs[level])
        return self.out(x).squeeze(-1)
