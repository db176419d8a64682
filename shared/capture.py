"""Whether a stimulus started a propagating wave: one definition for simulations and recordings.

A stimulus in a scar core (or in tissue too weakly excitable for its patch)
excites its own patch and nothing more; a captured stimulus launches a wave
that reaches most of the heart. The share of nodes that ever reach the
activation threshold separates the two by a wide margin: a patch of 10 mm
holds a few per cent of a ventricle's nodes, and a wave that propagates
reaches every node outside the scars, which cover at most half of the heart
(:func:`simgen.tissue.tissue_fields` refuses more). A stimulus *started a
wave* when that share exceeds :data:`CAPTURE_SHARE`.

For a simulation the share is over every node (finite activation times);
for a recording, over the observed nodes (the frames' peak at or above the
threshold).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InputError

__all__ = ["CAPTURE_SHARE", "activated_fraction", "recorded_fraction", "started_wave"]

#: Share of nodes (or of observed nodes) above which a stimulus counts as having started a wave.
CAPTURE_SHARE = 0.2


def activated_fraction(activation: ArrayLike) -> NDArray[np.float64]:
    """Share of the nodes each simulation activates: ``(S, N)`` activation times (NaN = never) -> ``(S,)``."""
    activation = np.asarray(activation)
    if activation.ndim != 2:
        raise InputError(f"activation must be (S, N), got shape {activation.shape}")
    return np.isfinite(activation).mean(axis=1)


def recorded_fraction(obs: ArrayLike, observed: ArrayLike, threshold: float = 0.5) -> NDArray[np.float64]:
    """Share of the observed nodes each recording shows activated: ``(K, T, N)`` potentials -> ``(K,)``.

    ``observed``: ``(N,)`` bool, the recorded nodes; a node counts when its
    ``u`` reaches ``threshold`` in any frame.
    """
    obs = np.asarray(obs)
    observed = np.asarray(observed, bool)
    if obs.ndim != 3 or observed.shape != (obs.shape[2],):
        raise InputError(f"obs must be (K, T, N) and observed (N,), got {obs.shape} and {observed.shape}")
    if not observed.any():
        raise InputError("no observed node")
    return (obs[:, :, observed].max(axis=1) >= threshold).mean(axis=1)


def started_wave(fraction: ArrayLike) -> NDArray[np.bool_]:
    """Whether each activated share (:func:`activated_fraction`, :func:`recorded_fraction`) means a wave."""
    return np.asarray(fraction) > CAPTURE_SHARE


#: Peak of ``u`` a node must reach for its crossing of 0.5 to count as an action potential in an activation map.
ACTION_POTENTIAL_PEAK = 0.8


def mapped_activation(
    activation: ArrayLike, peak: ArrayLike, noise: float = 0.0, rng: np.random.Generator | None = None
) -> NDArray[np.float64]:
    """Activation times as a mapping system records them: ``activation`` where the node fires an action
    potential (its peak ``u`` reaches :data:`ACTION_POTENTIAL_PEAK`), ``+inf`` where it never activates or only
    follows its neighbours passively (a scar core's electrotonic bump that touches 0.5 without firing); with
    ``noise``, Gaussian noise of that standard deviation (the units of ``activation``) from ``rng``, times kept
    at or after 0."""
    activation = np.asarray(activation, np.float64)
    fired = np.isfinite(activation) & (np.asarray(peak) >= ACTION_POTENTIAL_PEAK)
    mapped = np.where(fired, activation, np.inf)
    if noise > 0:
        if rng is None:
            raise InputError("noise > 0 needs an rng (np.random.Generator) for reproducible noise")
        mapped = np.maximum(mapped + rng.normal(0.0, noise, mapped.shape), 0.0)
    return mapped
