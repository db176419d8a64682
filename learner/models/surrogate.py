"""The generative surrogates: metaPNS (set-conditioned) and PNS (the same generator without c).

Generation for a stimulus ``s`` (a one-hot node map on the mesh)::

    z_0 = Linear(E_s(s))                      E_s: graph encoder + coarse blocks
    z_t = T(z_{t-1}, c),  t = 1..T            conditional gated transition, per coarse node
    x_t = G(z_t)                              graph decoder, one value per mesh node

With ``capture_gate`` metaPNS mixes the sequence with a no-wave response
``r_t``: ``x_t <- r_t + g (x_t - r_t)``, ``g = sigmoid(h(c_site, e_site))``
read from ``c`` and the stimulus features at the site's coarse node (with
``capture_evidence`` also from what the context set shows at the site itself,
:class:`~learner.models.site_evidence.SiteEvidence`).

metaPNS draws ``c`` from the context embedding q(c | Y); PNS has no ``c``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from learner.config import ModelConfig
from learner.ecg import LeadField
from learner.graph.geodesic import geodesic_distances
from learner.graph.hierarchy import MeshHierarchy
from learner.models.context_encoder import ContextEncoder
from learner.models.ecg_encoder import EcgEncoder
from learner.models.graph_decoder import GraphDecoder
from learner.models.graph_encoder import GraphEncoder
from learner.models.site_evidence import EVIDENCE_FEATURES, SiteEvidence
from learner.models.tissue_head import TissueHead
from learner.nn.gated_transition import ConditionalGatedTransition
from learner.nn.residual_block import ResidualGraphBlock

__all__ = ["Posterior", "PNS", "MetaPNS", "build_model"]

#: Initial logit of the capture gate: the gate starts open (0.88) and still steep (slope 0.10).
CAPTURE_BIAS = 2.0


@dataclass
class Posterior:
    """Diagonal Gaussian over ``c``: mean and log-variance, each ``(V, latent)``."""

    mu: Tensor
    logvar: Tensor

    def sample(self, generator: torch.Generator | None = None) -> Tensor:
        """One reparameterised draw ``mu + eps * sigma``."""
        eps = torch.randn(self.mu.shape, generator=generator, dtype=self.mu.dtype).to(self.mu.device)
        return self.mu + eps * torch.exp(0.5 * self.logvar)


class PNS(nn.Module):
    """Generic neural surrogate: stimulus site -> full-mesh sequence, the same for every subject."""

    conditioned = False

    def __init__(self, config: ModelConfig, frames: int) -> None:
        super().__init__()
        self.config, self.frames = config, frames
        ch, hid, lat = config.channels, config.hidden, config.latent
        self.stimulus_encoder = GraphEncoder(2 if config.stimulus_distance else 1, ch, hid, lat)
        self.coarse_blocks = nn.ModuleList(ResidualGraphBlock(lat, lat) for _ in range(config.coarse_blocks))
        self.initial_state = nn.Linear(lat, lat)
        self.transition = ConditionalGatedTransition(lat, self.conditioned, config.latent_norm)
        self.decoder = GraphDecoder(lat, ch, hid, skips=config.decoder_skips)
        self.context_stimulus: nn.Linear | None = None
        if self.conditioned and config.context_stimulus:
            self.context_stimulus = nn.Linear(lat, lat)
            nn.init.zeros_(self.context_stimulus.weight)  # starts as the model without it; gradients still reach it
            nn.init.zeros_(self.context_stimulus.bias)
        self.capture: nn.Sequential | None = None
        if self.conditioned and config.capture_gate:
            inputs = 2 * lat + (EVIDENCE_FEATURES if config.capture_evidence else 0)
            self.capture = nn.Sequential(nn.Linear(inputs, hid), nn.ELU(), nn.Linear(hid, 1))
            nn.init.zeros_(self.capture[-1].weight)  # every site starts with the same gate, sigmoid(2) = 0.88
            nn.init.constant_(self.capture[-1].bias, CAPTURE_BIAS)
            self.no_capture = nn.Parameter(torch.zeros(frames))  # r_t, one value per frame

    @torch.no_grad()
    def set_output_mean(self, mean: float) -> None:
        """Start as the mean predictor: a fresh decoder (zero output weights) then predicts ``mean`` everywhere.

        Its first errors are then the data's spread (~0.1) instead of ~0.7 for a
        random output layer, whose large early gradients push the whole network
        around before it has learned anything (docs/training.md).
        """
        self.decoder.out.bias.fill_(mean)
        if self.capture is not None:
            self.no_capture.fill_(mean)  # the gate then changes nothing until the two responses differ

    def initial(self, sites: Tensor, hierarchy: MeshHierarchy, c: Tensor | None = None) -> Tensor:
        """``z_0`` for stimulation node ids ``sites`` (S,): ``(S, V, latent)``."""
        return self._encode_stimulus(sites, hierarchy, c)[0]

    def capture_probability(
        self, sites: Tensor, hierarchy: MeshHierarchy, c: Tensor, evidence: SiteEvidence | None = None
    ) -> Tensor:
        """The gate ``g`` (S,): how likely a stimulus at each site starts a wave (``capture_gate`` only)."""
        return torch.sigmoid(self._encode_stimulus(sites, hierarchy, c, evidence)[2])

    def _encode_stimulus(
        self, sites: Tensor, hierarchy: MeshHierarchy, c: Tensor | None = None, evidence: SiteEvidence | None = None
    ) -> tuple[Tensor, list[Tensor], Tensor | None]:
        """``z_0``, the stimulus encoder's per-level features and the capture gate's logit (None without a gate).

        The stimulus is a one-hot node map; with ``stimulus_distance`` its
        geodesic distance map joins it as a second channel, so every node sees
        where the site is from the first layer on (a one-hot alone fades
        through mean aggregation and pooling, and the generator learns slowly).
        With ``context_stimulus`` a linear map of ``c`` is added to the coarse
        stimulus features before the coarse blocks: their mesh-wide receptive
        field can then tell whether the site lies in tissue that ``c`` marks as
        scar, where a stimulus launches no wave. The transition runs per node,
        so without it no node far from the site can know that.

        The capture gate reads ``c`` and the final coarse features at the
        site's coarse node, the one place where both the site and the tissue
        there are known, and gives one number per site for the whole mesh.
        With ``capture_evidence`` it also reads ``evidence`` at the site node.
        """
        n = hierarchy.graphs[0].num_nodes
        device = hierarchy.graphs[0].edge_index.device
        level0 = hierarchy.level0_sites(sites.to(device))  # the sites' working nodes on a working graph
        x = torch.zeros(len(sites), n, 1, device=device)
        x[torch.arange(len(sites), device=device), level0, 0] = 1.0
        if self.config.stimulus_distance:
            x = torch.cat([x, geodesic_distances(hierarchy.graphs[0], level0).unsqueeze(-1)], dim=-1)
        e, levels = self.stimulus_encoder.forward_levels(x, hierarchy)
        if self.context_stimulus is not None and c is not None:
            e = e + self.context_stimulus(c)
        for block in self.coarse_blocks:
            e = block(e, hierarchy.graphs[-1])
        gate = None
        if self.capture is not None and c is not None:
            node = hierarchy.coarsest_cluster(level0)
            rows = torch.arange(len(sites), device=device)
            inputs = [c[node], e[rows, node]]
            if self.config.capture_evidence:
                if evidence is None:
                    raise ValueError("this model's capture gate reads the context at the site: pass evidence")
                inputs.append(evidence.at(sites).to(e.dtype))
            gate = self.capture(torch.cat(inputs, dim=-1)).squeeze(-1)
        return self.initial_state(e), levels, gate

    def latent_path(self, sites: Tensor, hierarchy: MeshHierarchy, c: Tensor | None = None) -> Tensor:
        """Latent states ``z_1..z_T``: ``(S, T, V, latent)``."""
        return self._latent_path(self.initial(sites, hierarchy, c), c)

    def _latent_path(self, z: Tensor, c: Tensor | None) -> Tensor:
        cc = None if c is None else c.unsqueeze(0).expand_as(z)
        states = []
        for _ in range(self.frames):
            z = self.transition(z, cc)
            states.append(z)
        return torch.stack(states, dim=1)

    def generate(
        self,
        sites: Tensor,
        hierarchy: MeshHierarchy,
        c: Tensor | None = None,
        frames: Tensor | None = None,
        evidence: SiteEvidence | None = None,
    ) -> Tensor:
        """Predicted sequences ``(S, T, N)`` (or ``(S, len(frames), N)`` for a subset of frame indices).

        ``sites`` are mesh node ids and ``N`` the mesh's nodes; on a hierarchy
        with a working map the model runs on its working graph in between.

        ``evidence`` (the context set at node level) is required by a model with
        ``capture_evidence`` and ignored by every other.
        """
        return self.generate_with_gate(sites, hierarchy, c, frames, evidence)[0]

    def generate_with_gate(
        self,
        sites: Tensor,
        hierarchy: MeshHierarchy,
        c: Tensor | None = None,
        frames: Tensor | None = None,
        evidence: SiteEvidence | None = None,
    ) -> tuple[Tensor, Tensor | None]:
        """:meth:`generate`'s sequences and the capture gate's logit per site (S,), None without a gate."""
        z0, levels, logit = self._encode_stimulus(sites, hierarchy, c, evidence)
        z = self._latent_path(z0, c)
        if frames is not None:
            z = z[:, frames]
        s, t, v, l = z.shape
        skips = [f.repeat_interleave(t, dim=0) for f in levels] if self.config.decoder_skips else None
        x = hierarchy.to_mesh(self.decoder(z.reshape(s * t, v, l), hierarchy, skips).reshape(s, t, -1))
        if logit is None:
            return x, None
        rest = (self.no_capture if frames is None else self.no_capture[frames]).view(1, t, 1)
        return rest + torch.sigmoid(logit).view(s, 1, 1) * (x - rest), logit


class MetaPNS(PNS):
    """Personalised surrogate: the generator conditioned on an embedding ``c`` of the context set."""

    conditioned = True

    def __init__(self, config: ModelConfig, frames: int) -> None:
        super().__init__(config, frames)
        self.context_encoder = ContextEncoder(
            frames, config.channels, config.hidden, config.latent, config.context_stride
        )
        self.ecg_encoder = (
            EcgEncoder(frames, config.channels, config.hidden, config.latent) if config.ecg_encoder else None
        )
        self.maps_encoder = (
            ContextEncoder(frames, config.channels, config.hidden, config.latent, config.context_stride)
            if config.maps_encoder
            else None
        )
        self.tissue_head = TissueHead(config.latent, config.channels, config.hidden) if config.tissue_head else None

    def embed(
        self, obs: Tensor, observed: Tensor, hierarchy: MeshHierarchy, recorded: Tensor | None = None
    ) -> Posterior:
        """q(c | Y) from observed sequences ``obs`` (K, T, N) at the ``observed`` nodes (N,).

        ``recorded`` (K, T, N) marks, where the sequences are activation-time maps rendered through the action-
        potential template, the values the maps fix (:meth:`~learner.activation_maps.ApTemplate.fixed`). A model
        with a maps encoder reads maps through it and that mask; any other reads every frame of the observed
        nodes with its context encoder, as it was trained to.
        """
        if recorded is not None and self.maps_encoder is not None:
            return Posterior(*self.maps_encoder(obs, recorded, hierarchy))
        return Posterior(*self.context_encoder(obs, observed, hierarchy))

    def embed_ecg(self, ecg: Tensor, lead_field: LeadField, sites: Tensor, hierarchy: MeshHierarchy) -> Posterior:
        """q(c | ECGs) from the 12-lead ECGs ``ecg`` (K, 12, T) in mV of pacings at mesh nodes ``sites`` (K,)."""
        if self.ecg_encoder is None:
            raise ValueError("this model reads no ECGs: it was built without model.ecg_encoder")
        return Posterior(*self.ecg_encoder(ecg, lead_field, sites, hierarchy))

    def tissue(self, c: Tensor, hierarchy: MeshHierarchy) -> tuple[Tensor, Tensor]:
        """What a draw of ``c`` says about the tissue: abnormal-tissue logits on the mesh's nodes ``(N,)`` and the
        healthy tissue's log conduction velocity (m/s) ``()`` (:class:`~learner.models.tissue_head.TissueHead`)."""
        if self.tissue_head is None:
            raise ValueError("this model infers no tissue: it was built without model.tissue_head")
        return self.tissue_head(c, hierarchy)

    def embed_prior_and_posterior(
        self, context: Tensor, extra: Tensor, observed: Tensor, hierarchy: MeshHierarchy
    ) -> tuple[Posterior, Posterior]:
        """p(c | Y) from ``context`` and q(c | Y u X) from ``context`` plus ``extra``, encoding each sequence once."""
        h = self.context_encoder.embed_sequences(torch.cat([context, extra]), observed, hierarchy)
        enc = self.context_encoder
        return Posterior(*enc.distribution(h[: len(context)])), Posterior(*enc.distribution(h))


def build_model(config: ModelConfig, frames: int) -> PNS:
    """The model named by ``config.kind`` for sequences of ``frames`` frames."""
    return (MetaPNS if config.kind == "metapns" else PNS)(config, frames)
