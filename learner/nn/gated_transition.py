r"""Conditional gated transition of the latent state, per node (no graph convolution).

.. math::

    z_1 &= \mathrm{ELU}(\alpha_1 z + \beta_1 c + \gamma_1), & g &= \sigma(W_1 z_1 + b_1) \\
    z_2 &= \mathrm{ELU}(\alpha_2 z + \beta_2 c + \gamma_2), & h &= \mathrm{ELU}(W_2 z_2 + b_2) \\
    z_3 &= \alpha_3 z + \beta_3 c + \gamma_3, & z' &= \mathrm{LN}\big((1 - g)(W_3 z_3 + b_3) + g\, h\big)

with :math:`\alpha_i, \beta_i, \gamma_i` learnable per-channel vectors; the
unconditioned variant (PNS) has no :math:`\beta_i c` terms. ``LN`` is a layer
normalisation over the channels of each node (with a learnable scale and shift):
the transition runs once per frame, so without it any expansive map (gain above
1 on the linear path) grows the state geometrically over the sequence. Training
without it diverged that way: the last frame's state rose from ~30 to 5e4 within
eleven steps, then the loss spiked (docs/training.md). ``normalize=False``
gives the unnormalised transition of the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.functional import elu

from shared.errors import InputError

__all__ = ["ConditionalGatedTransition"]


class ConditionalGatedTransition(nn.Module):
    """``z (B, V, L)``, ``c (B, V, L) | None -> z' (B, V, L)``.

    ``c`` may be any shape broadcastable to ``z`` (e.g. ``(1, V, L)`` for one
    subject's embedding shared by a batch of sequences).

    Initialisation: the linear path starts at the identity
    (:math:`W_3 = I, b_3 = 0, \\alpha_3 = 1, \\gamma_3 = 0, \\beta_3 = 0`), as in the
    reference; :math:`\\alpha_{1,2} = 1, \\beta_{1,2} = 1, \\gamma_{1,2} = 0`, so
    ``c`` enters the gate and the candidate from the start.
    """

    def __init__(self, latent: int, conditioned: bool = True, normalize: bool = True) -> None:
        super().__init__()
        if latent < 1:
            raise InputError(f"latent must be >= 1, got {latent}")
        self.latent, self.conditioned = latent, conditioned
        self.norm = nn.LayerNorm(latent) if normalize else nn.Identity()
        for i in (1, 2, 3):
            setattr(self, f"alpha{i}", nn.Parameter(torch.empty(latent)))
            setattr(self, f"gamma{i}", nn.Parameter(torch.empty(latent)))
            if conditioned:
                setattr(self, f"beta{i}", nn.Parameter(torch.empty(latent)))
        self.lin1 = nn.Linear(latent, latent)
        self.lin2 = nn.Linear(latent, latent)
        self.lin3 = nn.Linear(latent, latent)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        with torch.no_grad():
            for i in (1, 2, 3):
                getattr(self, f"alpha{i}").fill_(1.0)
                getattr(self, f"gamma{i}").zero_()
                if self.conditioned:
                    getattr(self, f"beta{i}").fill_(0.0 if i == 3 else 1.0)
            self.lin1.reset_parameters()
            self.lin2.reset_parameters()
            self.lin3.weight.copy_(torch.eye(self.latent))
            self.lin3.bias.zero_()
            if isinstance(self.norm, nn.LayerNorm):
                self.norm.reset_parameters()

    def _affine(self, i: int, z: Tensor, c: Tensor | None) -> Tensor:
        y = getattr(self, f"alpha{i}") * z + getattr(self, f"gamma{i}")
        return y if c is None else y + getattr(self, f"beta{i}") * c

    def forward(self, z: Tensor, c: Tensor | None = None) -> Tensor:
        if z.shape[-1] != self.latent:
            raise InputError(f"z must have {self.latent} channels in its last dim, got shape {tuple(z.shape)}")
        if self.conditioned:
            if c is None:
                raise InputError("a conditioned transition needs c (use conditioned=False for PNS)")
            if c.shape[-1] != self.latent or c.dim() > z.dim():
                raise InputError(f"c of shape {tuple(c.shape)} does not match z of shape {tuple(z.shape)}")
            # by hand: torch.broadcast_shapes imports torch._refs on its first call, half a second
            if any(a != b and 1 not in (a, b) for a, b in zip(reversed(z.shape), reversed(c.shape))):
                raise InputError(f"c of shape {tuple(c.shape)} does not broadcast to z {tuple(z.shape)}")
        elif c is not None:
            raise InputError("this transition is unconditioned (conditioned=False) and takes no c")
        g = torch.sigmoid(self.lin1(elu(self._affine(1, z, c))))
        h = elu(self.lin2(elu(self._affine(2, z, c))))
        return self.norm((1 - g) * self.lin3(self._affine(3, z, c)) + g * h)

    def extra_repr(self) -> str:
        return f"latent={self.latent}, conditioned={self.conditioned}"
