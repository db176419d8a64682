"""Activation-time maps as recordings: potentials rendered from each mapped node's activation time.

Electroanatomical mapping systems export one local activation time per mapped
point; a model reads potential sequences at its frames. A map becomes
potentials through the action-potential template of the model's training
data (:class:`ApTemplate`): at a node activated at time ``a``,
``u(t) = template(t - a)``, the median waveform of the training simulations
aligned at their first crossing of ``u = 0.5`` (foot, upstroke, plateau and
repolarisation as the model saw them). A node mapped as never activated
(``+inf``) stays at rest.

A map fixes a node's potential only up to the end of its upstroke: at rest
before, rising at the time mapped. What follows (plateau height, action
potential duration) depends on the tissue, and scar and border zone repolarise
earlier than the healthy template; rendered, those frames would tell the model
that scarred tissue is healthy. :meth:`ApTemplate.fixed` marks the frames a map
fixes (up to :attr:`ApTemplate.upstroke_end` after each activation, and every
frame of a node never activated); the model reads the others as unrecorded, as
it reads unobserved nodes.

The template ships with the weights, like torchvision's ``weights.transforms()``:
a shipped model's config.json holds it (``ap_template``); a training
checkpoint's is computed from its training store (:func:`template_from_store`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.errors import InputError

__all__ = ["ApTemplate", "UPSTROKE_SHARE", "template_from_sequences", "template_from_store"]

#: Offset step of a template (model time units; 0.1 = 1.29 ms).
TEMPLATE_STEP = 0.1
#: The upstroke ends where the template first reaches this share of its peak.
UPSTROKE_SHARE = 0.95


@dataclass(frozen=True)
class ApTemplate:
    """An action-potential waveform ``u`` at ``offsets`` (model time units) from the activation time."""

    offsets: np.ndarray  # (P,) increasing
    u: np.ndarray  # (P,)

    def render(self, activation: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Potentials ``(K, T, N)`` at frame ``times`` (T,) of activation times ``(K, N)`` (model time units).

        ``+inf``: never activated (rest throughout); NaN: unmapped (0, to be masked by the caller).
        """
        activation = np.asarray(activation, np.float64)
        shift = np.asarray(times, np.float64)[None, :, None] - activation[:, None, :]
        with np.errstate(invalid="ignore"):
            u = np.interp(shift, self.offsets, self.u, left=self.u[0], right=self.u[-1])
        return np.where(np.isnan(shift), 0.0, u).astype(np.float32)

    @property
    def upstroke_end(self) -> float:
        """Offset (model time units) at which the upstroke ends: the first offset >= 0 where the template reaches
        :data:`UPSTROKE_SHARE` of its peak."""
        after = self.offsets >= 0
        reached = after & (self.u >= UPSTROKE_SHARE * self.u.max())
        return float(self.offsets[np.argmax(reached)] if reached.any() else self.offsets[-1])

    def fixed(self, activation: np.ndarray, times: np.ndarray) -> np.ndarray:
        """``(K, T, N)`` bool: the frames at ``times`` whose potential activation times ``(K, N)`` fix (module
        docstring): up to :attr:`upstroke_end` after the activation, every frame where never activated (``+inf``),
        none where unmapped (NaN)."""
        activation = np.asarray(activation, np.float64)
        with np.errstate(invalid="ignore"):
            return np.asarray(times, np.float64)[None, :, None] <= activation[:, None, :] + self.upstroke_end

    def to_dict(self) -> dict[str, list[float]]:
        """The template as JSON-ready lists (:meth:`from_dict` inverts it)."""
        return {
            "offsets": [round(float(v), 6) for v in self.offsets],
            "u": [round(float(v), 6) for v in self.u],
        }

    @classmethod
    def from_dict(cls, data: dict) -> ApTemplate:
        """A template from :meth:`to_dict`'s lists, checked."""
        try:
            offsets, u = np.asarray(data["offsets"], np.float64), np.asarray(data["u"], np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"ap_template must hold lists 'offsets' and 'u' of numbers: {exc}") from None
        if offsets.ndim != 1 or offsets.shape != u.shape or len(u) < 2 or not np.isfinite([*offsets, *u]).all():
            raise InputError("ap_template: 'offsets' and 'u' must be finite lists of the same length (>= 2)")
        if np.any(np.diff(offsets) <= 0):
            raise InputError("ap_template: 'offsets' must increase")
        return cls(offsets, u)


def template_from_sequences(
    u: np.ndarray, times: np.ndarray, threshold: float = 0.5, max_series: int = 20_000, seed: int = 0
) -> ApTemplate:
    """The median waveform of simulated sequences ``u`` (S, T, N) at ``times`` (T,), aligned at activation.

    Up to ``max_series`` activated (site, node) series, drawn at random, are
    each sampled at ``a + offset`` within the recorded frames; offsets span the
    frames' length either side of the activation. Where no series reaches an
    offset, the template holds rest before the activation and the last median
    after it.
    """
    from learner.metrics import activation_times

    u = np.asarray(u, np.float64)
    times = np.asarray(times, np.float64)
    series = u.transpose(0, 2, 1).reshape(-1, u.shape[1])  # (S*N, T)
    act = np.concatenate([activation_times(sequence, times, threshold) for sequence in u])
    keep = np.flatnonzero(np.isfinite(act))
    if not len(keep):
        raise InputError("no node of these simulations activates: no action potential to take a template from")
    keep = np.sort(np.random.default_rng(seed).choice(keep, min(max_series, len(keep)), replace=False))
    span = times[-1] - times[0]
    offsets = np.round(np.arange(-span, span + TEMPLATE_STEP / 2, TEMPLATE_STEP), 6)
    at = act[keep, None] + offsets[None, :]  # (M, P) the times each series is sampled at
    right = np.clip(np.searchsorted(times, at), 1, len(times) - 1)
    w = (at - times[right - 1]) / (times[right] - times[right - 1])
    rows = series[keep]
    sampled = (1 - w) * np.take_along_axis(rows, right - 1, axis=1) + w * np.take_along_axis(rows, right, axis=1)
    sampled[(at < times[0]) | (at > times[-1])] = np.nan
    counted = np.isfinite(sampled).any(axis=0)
    median = np.zeros(len(offsets))
    median[counted] = np.nanmedian(sampled[:, counted], axis=0)
    last = np.flatnonzero(counted)[-1]
    median[last + 1 :] = median[last]
    return ApTemplate(offsets, median)


def template_from_store(
    store: str | Path,
    subjects: list[str],
    max_subjects: int = 32,
    sites_per_subject: int = 4,
    nodes_per_subject: int = 2_000,
    seed: int = 0,
) -> ApTemplate:
    """:func:`template_from_sequences` of ``sites_per_subject`` simulations and ``nodes_per_subject`` nodes
    of each of up to ``max_subjects`` of ``subjects`` (of every subject of the store where the list is
    empty), all drawn at random."""
    from learner.store_view import StoreView
    from shared.reader import read_u

    view = StoreView(store)
    rng = np.random.default_rng(seed)
    parts = []
    subjects = sorted(subjects or view.subjects)
    for subject in rng.choice(subjects, min(max_subjects, len(subjects)), replace=False):
        rows = len(view.sites(view.mesh_of[subject]))
        u = read_u(store, subject, np.sort(rng.choice(rows, min(sites_per_subject, rows), replace=False)))
        nodes = np.sort(rng.choice(u.shape[2], min(nodes_per_subject, u.shape[2]), replace=False))
        parts.append(u[:, :, nodes].transpose(1, 0, 2).reshape(u.shape[1], -1))  # (T, sites * nodes)
    return template_from_sequences(np.concatenate(parts, axis=1)[None], view.times, seed=seed)
