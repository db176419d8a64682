"""The meta-model from ECGs: q(c | the 12-lead ECGs of the context pacings)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from learner.ecg import LeadField, normalised_ecg
from learner.graph.geodesic import geodesic_distances
from learner.graph.hierarchy import MeshHierarchy
from learner.models.context_encoder import INITIAL_LOGVAR
from learner.models.graph_encoder import GraphEncoder
from shared.ecg import LEADS

__all__ = ["EcgEncoder", "ECG_CODE"]

#: Channels of each recording's code from its 12 leads over time, given to every node.
ECG_CODE = 32


class EcgEncoder(nn.Module):
    r"""ECGs ``(K, 12, T)`` of pacings at ``sites`` (K,) to :math:`(\mu_c, \log\sigma^2_c)`, like
    :class:`~learner.models.context_encoder.ContextEncoder` but from the body surface.

    An ECG has no node values, so each recording is given to every node of the working graph as:
    the lead field's density there (12, :class:`~learner.ecg.LeadField`), the leads back-projected through it
    at every frame (``sum_l density_l e_l(t)``, T channels: where activity at each moment would show), the
    site (one-hot and geodesic distance: an ECG means something only with where the pacing was) and a code of
    the whole ECG (an MLP over its leads and frames, :data:`ECG_CODE` channels). The graph encoder maps these
    to per-coarse-node embeddings, averaged over the set as in the potential encoder. The ECGs are scaled by
    the set's largest magnitude (:func:`~learner.ecg.normalised_ecg`) first.
    """

    def __init__(self, frames: int, channels: tuple[int, ...], hidden: int, latent: int) -> None:
        super().__init__()
        self.frames = frames
        leads = len(LEADS)
        self.code = nn.Sequential(nn.Linear(leads * frames, hidden), nn.ELU(), nn.Linear(hidden, ECG_CODE), nn.Tanh())
        self.encoder = GraphEncoder(leads + frames + 2 + ECG_CODE, channels, hidden, latent)
        self.mu = nn.Linear(latent, latent)
        self.logvar = nn.Linear(latent, latent)
        nn.init.constant_(self.logvar.bias, INITIAL_LOGVAR)

    def node_inputs(self, ecg: Tensor, lead_field: LeadField, sites: Tensor, hierarchy: MeshHierarchy) -> Tensor:
        """The encoder's inputs ``(K, n_0, C)`` at the working graph's nodes (class docstring)."""
        k, n_leads, t = ecg.shape
        if (n_leads, t) != (len(LEADS), self.frames):
            raise ValueError(f"context ECGs are {tuple(ecg.shape)}, the model reads (K, {len(LEADS)}, {self.frames})")
        e = normalised_ecg(ecg)
        mesh_nodes = lead_field.density.shape[0]
        every = torch.ones(mesh_nodes, dtype=torch.bool, device=e.device)
        density, _ = hierarchy.level0_observations(lead_field.density.T.unsqueeze(0).to(e), every)
        density = density[0].T  # (n_0, 12)
        n0 = density.shape[0]
        back = torch.einsum("klt,nl->knt", e, density) / n_leads
        level0 = hierarchy.level0_sites(sites.to(e.device))
        one_hot = torch.zeros(k, n0, 1, device=e.device, dtype=e.dtype)
        one_hot[torch.arange(k, device=e.device), level0, 0] = 1.0
        distance = geodesic_distances(hierarchy.graphs[0], level0).to(e.dtype).unsqueeze(-1)
        code = self.code(e.reshape(k, -1))
        parts = [density.expand(k, n0, n_leads), back, one_hot, distance, code.unsqueeze(1).expand(k, n0, ECG_CODE)]
        return torch.cat(parts, dim=-1)

    def forward(
        self, ecg: Tensor, lead_field: LeadField, sites: Tensor, hierarchy: MeshHierarchy
    ) -> tuple[Tensor, Tensor]:
        h = self.encoder(self.node_inputs(ecg, lead_field, sites, hierarchy), hierarchy)  # (K, V, L)
        pooled = h.mean(dim=0)
        return self.mu(pooled), self.logvar(pooled).clamp(-10.0, 10.0)
