"""The surrogates: PNS and the meta-learned MetaPNS, their encoders and decoder, and the site evidence.

:func:`build_model` makes the model a config names; :class:`~learner.models.surrogate.Posterior` is
the context encoder's Gaussian over the latent tissue code ``c``.
"""

from __future__ import annotations

from learner.models.context_encoder import ContextEncoder
from learner.models.graph_decoder import GraphDecoder
from learner.models.graph_encoder import GraphEncoder
from learner.models.site_evidence import EVIDENCE_FEATURES, SiteEvidence
from learner.models.surrogate import PNS, MetaPNS, Posterior, build_model

__all__ = [
    "PNS",
    "MetaPNS",
    "Posterior",
    "build_model",
    "ContextEncoder",
    "GraphEncoder",
    "GraphDecoder",
    "SiteEvidence",
    "EVIDENCE_FEATURES",
]
