"""Observation operators: which nodes the learner's encoders see.

The full field lives on all mesh nodes; observations live on all surface
nodes, the epicardium only, or the electrodes of a sparse epicardial sock,
optionally noisy. Kinds are named as the store names the node sets
(:data:`shared.observation.OBSERVATION_SETS`); the noise is
:func:`shared.observation.observe`'s.
"""

from __future__ import annotations

from typing import Any

from shared.errors import InputError
from simgen.observe.base import ObservationOperator
from simgen.observe.node_sets import AllSurface, Epicardial, NodeSetObservation
from simgen.observe.sock import Sock, electrode_spacing, farthest_point_sampling

__all__ = [
    "ObservationOperator",
    "NodeSetObservation",
    "AllSurface",
    "Epicardial",
    "Sock",
    "OBSERVATION_KINDS",
    "make_observation",
    "electrode_spacing",
    "farthest_point_sampling",
]

#: Observation kinds accepted by :func:`make_observation`.
OBSERVATION_KINDS: dict[str, type[ObservationOperator]] = {
    "surface": AllSurface,
    "epicardium": Epicardial,
    "electrodes": Sock,
}


def make_observation(kind: str, **kwargs: Any) -> ObservationOperator:
    """Observation operator of ``kind`` ("surface", "epicardium" or "electrodes": the sock).

    Keyword arguments go to the operator (``noise_std``, ``seed``, and
    ``n_electrodes`` for the sock).
    """
    try:
        cls = OBSERVATION_KINDS[kind]
    except (KeyError, TypeError):
        raise InputError(f"unknown observation kind {kind!r}; allowed kinds: {', '.join(OBSERVATION_KINDS)}") from None
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise InputError(f"observation kind {kind!r}: {exc}") from None
