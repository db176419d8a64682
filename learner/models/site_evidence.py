"""What a subject's context set shows at a stimulation node: the capture gate's direct evidence.

A stimulus inside a dense scar core starts a wave only when the tissue there
can still be excited. The context set answers that at node level: a node
that never depolarises while waves started elsewhere pass by is unexcitable.
On the default store the peak of ``u`` at a scar-core site over 5 context
simulations separates the sites that start a wave from those that do not
with an AUC of 0.91 (docs/training.md), information that the coarse
embedding ``c`` (one vector per ~40 nodes) blurs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from learner.data.episodes import Episode

__all__ = ["EVIDENCE_FEATURES", "SiteEvidence"]

#: Features per site: the peak over context sequences stimulated elsewhere, and whether there is one.
EVIDENCE_FEATURES = 2


@dataclass(frozen=True)
class SiteEvidence:
    """Per context sequence, the peak observed value at every node, and where that sequence was stimulated.

    Attributes
    ----------
    peaks : FloatTensor (K, N)
        Maximum over frames of each context sequence; 0 on unobserved nodes.
    sites : LongTensor (K,)
        Stimulation node of each context sequence.
    observed : BoolTensor (N,)
        Observation mask.
    """

    peaks: Tensor
    sites: Tensor
    observed: Tensor

    @classmethod
    def from_context(cls, obs: Tensor, observed: Tensor, sites: Tensor) -> SiteEvidence:
        """From observed context sequences ``obs`` (K, T, N), the mask (N,) and their sites (K,)."""
        if obs.ndim != 3 or len(sites) != len(obs) or obs.shape[-1] != observed.shape[-1]:
            raise ValueError(
                f"context of shape {tuple(obs.shape)} does not match {len(sites)} sites and {observed.shape[-1]} nodes"
            )
        observed = observed.bool()
        return cls(obs.amax(dim=1) * observed, sites.long().to(obs.device), observed)

    @classmethod
    def of(cls, episode: Episode) -> SiteEvidence:
        """The evidence of an episode's context set."""
        return cls.from_context(episode.context_obs, episode.observed, episode.context_sites)

    def to(self, device: torch.device | str) -> SiteEvidence:
        """A copy on ``device``."""
        return SiteEvidence(self.peaks.to(device), self.sites.to(device), self.observed.to(device))

    def at(self, nodes: Tensor) -> Tensor:
        """``(S, 2)`` features of stimulation nodes: the peak there over the context sequences stimulated elsewhere,
        and a flag, 1 where there is such a peak.

        A sequence stimulated at the node itself is left out (its stimulus alone
        raises ``u`` there, wave or not). Where the node is unobserved or only
        its own sequence is in the set, both features are 0.
        """
        nodes = nodes.long().to(self.peaks.device)
        others = self.sites.unsqueeze(0) != nodes.unsqueeze(1)  # (S, K)
        known = others & self.observed[nodes].unsqueeze(1)
        values = torch.where(known, self.peaks[:, nodes].T, torch.zeros((), dtype=self.peaks.dtype))
        return torch.stack([values.amax(dim=1), known.any(dim=1).to(self.peaks.dtype)], dim=1)
