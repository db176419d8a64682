"""A small variational autoencoder of excitability maps: the generative tissue model of VAE-BO.

Maps are scaled to :math:`m = (a - a_h) / (a_s - a_h) \\in [0, 1]` and encoded
by an MLP to a Gaussian :math:`q(z \\mid m) = \\mathcal N(\\mu, \\sigma^2)` in
``latent`` dimensions; the decoder MLP gives per-node logits, so a decoded map
is :math:`a = a_h + (a_s - a_h)\\,\\mathrm{sigmoid}(\\mathrm{logits})`. Training
minimises the negative ELBO, per map

.. math::

    \\mathcal L = \\sum_i \\mathrm{BCE}(\\mathrm{logits}_i, m_i)
        + \\beta\\, \\mathrm{KL}\\big(\\mathcal N(\\mu, \\sigma^2) \\,\\|\\, \\mathcal N(0, I)\\big),

so the prior region of the latent space (a box of a few standard deviations)
decodes to library-like maps, which is where VAE-BO searches.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import Tensor, nn
from torch.nn import functional as F

from learner.baselines.threads import torch_threads
from shared.errors import InputError

__all__ = ["TissueVAE", "train_tissue_vae"]

_A_LOW, _A_HIGH = 0.15, 0.5


class TissueVAE(nn.Module):
    """MLP VAE of per-node excitability maps on one mesh.

    Parameters
    ----------
    nodes : mesh nodes N (input and output width).
    latent : latent dimension d.
    hidden : width of the one hidden layer of encoder and decoder.
    """

    def __init__(self, nodes: int, latent: int = 3, hidden: int = 128) -> None:
        super().__init__()
        if nodes < 1 or latent < 1 or hidden < 1:
            raise InputError(f"nodes, latent and hidden must be >= 1, got {nodes}, {latent}, {hidden}")
        self.nodes, self.latent, self.hidden = nodes, latent, hidden
        self.encoder = nn.Sequential(nn.Linear(nodes, hidden), nn.ELU())
        self.to_mu = nn.Linear(hidden, latent)
        self.to_logvar = nn.Linear(hidden, latent)
        self.decoder = nn.Sequential(nn.Linear(latent, hidden), nn.ELU(), nn.Linear(hidden, nodes))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Linear):
                module.reset_parameters()

    def encode(self, m: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and log-variance (B, d) of q(z | m) for scaled maps ``m`` (B, N)."""
        h = self.encoder(m)
        return self.to_mu(h), self.to_logvar(h)

    def logits(self, z: Tensor) -> Tensor:
        """Per-node logits (B, N) of latent points ``z`` (B, d)."""
        return self.decoder(z)

    def forward(self, m: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Reconstruction logits, mean and log-variance of a batch of scaled maps (sampling z)."""
        mu, logvar = self.encode(m)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)
        return self.logits(z), mu, logvar

    def decode(self, z: ArrayLike) -> NDArray[np.float64]:
        """Excitability map(s) of latent point(s) ``z``: (d,) -> (N,), (B, d) -> (B, N)."""
        zt = torch.as_tensor(np.asarray(z, dtype=np.float32))
        if zt.shape[-1] != self.latent or zt.dim() not in (1, 2):
            raise InputError(f"latent points must have shape (d={self.latent},) or (B, d), got {tuple(zt.shape)}")
        with torch.no_grad():
            m = torch.sigmoid(self.logits(zt.reshape(-1, self.latent))).double().numpy()
        a = _A_LOW + (_A_HIGH - _A_LOW) * m
        return a.reshape(*zt.shape[:-1], self.nodes)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(nodes={self.nodes}, latent={self.latent}, hidden={self.hidden})"


def train_tissue_vae(
    maps: ArrayLike,
    latent: int = 3,
    hidden: int = 128,
    epochs: int = 200,
    batch_size: int = 100,
    lr: float = 3e-3,
    beta: float = 1.0,
    seed: int = 0,
) -> TissueVAE:
    """Train a :class:`TissueVAE` on excitability ``maps`` (M, N) with Adam; deterministic for a seed.

    Values are clipped to [0.15, 0.5] before scaling. Runs on one torch thread;
    torch's global generator is left as it was.
    """
    a = np.asarray(maps, dtype=np.float32)
    if a.ndim != 2 or a.shape[0] < 2 or a.shape[1] < 1:
        raise InputError(f"maps must be an (M >= 2, N) array of excitability maps, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise InputError("maps contain NaN or inf")
    if epochs < 1 or batch_size < 1 or not lr > 0 or not beta >= 0:
        raise InputError(f"need epochs, batch_size >= 1, lr > 0, beta >= 0; got {epochs}, {batch_size}, {lr}, {beta}")
    m = torch.from_numpy((np.clip(a, _A_LOW, _A_HIGH) - _A_LOW) / (_A_HIGH - _A_LOW))
    with torch.random.fork_rng(), torch_threads(1):
        torch.manual_seed(seed)
        model = TissueVAE(a.shape[1], latent, hidden)
        opt = torch.optim.Adam(model.parameters(), lr=lr)
        model.train()
        for _ in range(epochs):
            for idx in torch.randperm(len(m)).split(batch_size):
                batch = m[idx]
                logits, mu, logvar = model(batch)
                rec = F.binary_cross_entropy_with_logits(logits, batch, reduction="sum")
                kl = -0.5 * torch.sum(1 + logvar - mu.pow(2) - logvar.exp())
                loss = (rec + beta * kl) / len(batch)
                opt.zero_grad()
                loss.backward()
                opt.step()
    model.eval()
    return model
