"""Observation operator base: which nodes an encoder sees, plus optional noise.

The full field ``x`` lives on all ``N`` mesh nodes; an observation ``y`` is its
restriction to a sorted subset of nodes, optionally with additive Gaussian
noise, ``y = (x + noise_std * e)[..., idx]``, ``e ~ N(0, I)`` (``u`` units):
the observation model of :mod:`shared.observation`, which training episodes
and the benchmark use too.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InputError
from shared.mesh import Mesh
from shared.observation import check_noise_std, observe

__all__ = ["ObservationOperator"]


@dataclass(frozen=True)
class ObservationOperator(ABC):
    """Restriction of a nodal field to observed nodes, with optional noise.

    Parameters
    ----------
    name : the node set's name in the store (:data:`shared.observation.OBSERVATION_SETS`).
    noise_std : standard deviation of additive Gaussian noise, in units of ``u``.
    seed : seed of the default noise generator, so repeated calls are reproducible.
    """

    name: str
    noise_std: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_noise_std(self.noise_std)

    @abstractmethod
    def indices(self, mesh: Mesh) -> NDArray[np.int32]:
        """Sorted, unique ids of the observed nodes of ``mesh``."""

    def mask(self, mesh: Mesh) -> NDArray[np.bool_]:
        """Boolean (N,) array, True at observed nodes."""
        out = np.zeros(mesh.n_nodes, dtype=bool)
        out[self.indices(mesh)] = True
        return out

    def observe(self, mesh: Mesh, u: ArrayLike, rng: np.random.Generator | None = None) -> NDArray[np.float32]:
        """Observed values ``u[..., indices]`` (float32) plus noise (:func:`shared.observation.observe`).

        Parameters
        ----------
        mesh : the mesh ``u`` lives on.
        u : field with nodes on the last axis, e.g. (N,), (T, N) or (S, T, N).
        rng : noise generator; ``np.random.default_rng(self.seed)`` when ``None``.
        """
        u = np.asarray(u)
        if u.ndim == 0 or u.shape[-1] != mesh.n_nodes:
            raise InputError(
                f"observation {self.name!r}: u must have the {mesh.n_nodes} nodes of mesh "
                f"{mesh.name!r} on its last axis, got shape {u.shape}"
            )
        if not np.issubdtype(u.dtype, np.number) or not np.all(np.isfinite(u)):
            raise InputError(f"observation {self.name!r}: u contains NaN, infinite or non-numeric values")
        idx = self.indices(mesh)
        observed = np.zeros(mesh.n_nodes, dtype=bool)
        observed[idx] = True
        rng = np.random.default_rng(self.seed) if rng is None else rng
        return observe(u, observed, self.noise_std, rng)[..., idx]
