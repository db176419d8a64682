"""The observation model: which nodes of a simulated field are observed, and the Gaussian noise on them.

Simulation data (``simgen.observe``), training episodes (``learner.data.episodes``) and the
benchmark (``learner.benchmark``) all observe through :func:`observe`. An observation of a
nodal field ``u`` (nodes on the last axis) through the node set ``S`` with noise standard
deviation ``s`` is

.. math:: y = (u + s\\,e) \\odot 1_S, \\qquad e \\sim \\mathcal N(0, I),

with ``e`` drawn in float32 from a NumPy ``Generator`` over the whole field, so the draws do not
depend on ``S``; ``y[..., S]`` is the restriction to the observed nodes.

Node sets are named as the store names them (:data:`OBSERVATION_SETS`): ``"electrodes"`` is the
sparse epicardial sock, ``"all"`` every node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from shared.errors import InputError, SchemaError
from shared.schema import MESH_INDEX_SETS

__all__ = [
    "OBSERVATION_SETS",
    "Observation",
    "check_observation_set",
    "check_noise_std",
    "node_mask",
    "gaussian_noise",
    "observe",
]

#: Node sets an observation may use: a stored mesh node set (the sock's ``"electrodes"`` among them), or every node.
OBSERVATION_SETS = (*MESH_INDEX_SETS, "all")


def check_observation_set(name: str) -> str:
    """``name`` if it is one of :data:`OBSERVATION_SETS`; :class:`InputError` otherwise."""
    if name not in OBSERVATION_SETS:
        raise InputError(f"unknown observation set {name!r}; choose one of {', '.join(OBSERVATION_SETS)}")
    return name


def check_noise_std(noise_std: float) -> float:
    """``noise_std`` if it is a finite number >= 0; :class:`InputError` otherwise."""
    ok = isinstance(noise_std, (int, float, np.floating, np.integer)) and not isinstance(noise_std, bool)
    if not (ok and np.isfinite(noise_std) and noise_std >= 0):
        raise InputError(f"noise_std must be a finite number >= 0, got {noise_std!r}")
    return noise_std


def node_mask(n_nodes: int, ids: ArrayLike, name: str = "observed", mesh_id: str = "") -> NDArray[np.bool_]:
    """(n_nodes,) bool, True at the node ids ``ids`` of node set ``name`` of mesh ``mesh_id``.

    An empty set is bad input (nothing would be observed); ids outside ``[0, n_nodes)`` are a
    damaged store (:class:`SchemaError`).
    """
    ids = np.asarray(ids)
    if ids.size == 0:
        raise InputError(f"mesh {mesh_id!r} has an empty {name!r} node set: nothing would be observed")
    if ids.min() < 0 or ids.max() >= n_nodes:
        raise SchemaError(f"node set {name!r} of mesh {mesh_id!r} has ids outside [0, {n_nodes})")
    mask = np.zeros(n_nodes, dtype=bool)
    mask[ids] = True
    return mask


def gaussian_noise(
    shape: tuple[int, ...], noise_std: float, rng: np.random.Generator, dtype: DTypeLike = np.float32
) -> NDArray[np.floating]:
    """``noise_std * e``, ``e ~ N(0, I)`` of ``shape``, drawn from ``rng`` in ``dtype`` (float32 or float64)."""
    dtype = np.dtype(dtype)
    return dtype.type(noise_std) * rng.standard_normal(shape, dtype=dtype)


def observe(
    u: ArrayLike, observed: NDArray[np.bool_], noise_std: float = 0.0, rng: np.random.Generator | None = None
) -> NDArray[np.float32]:
    """``u`` (float32, nodes on the last axis) plus noise, zero at the nodes ``observed`` is False at.

    Parameters
    ----------
    u : field with the ``N`` nodes on its last axis, e.g. (N,), (T, N) or (K, T, N).
    observed : (N,) bool mask of the observed nodes.
    noise_std, rng : noise standard deviation (``u`` units) and its generator, required when
        ``noise_std > 0``: one float32 draw per entry of ``u``, unobserved nodes included.
    """
    if noise_std > 0 and rng is None:
        raise InputError("noise_std > 0 needs an rng (np.random.Generator) for reproducible noise")
    y = np.array(u, dtype=np.float32)
    if noise_std > 0:
        y += gaussian_noise(y.shape, noise_std, rng)
    y[..., ~observed] = 0.0  # unobserved nodes carry no information, noise included
    return y


@dataclass(frozen=True)
class Observation:
    """An observation setting: the node set observed (one of :data:`OBSERVATION_SETS`) and the noise on it."""

    nodes: str = "surface"
    noise_std: float = 0.0

    def __post_init__(self) -> None:
        check_observation_set(self.nodes)
        check_noise_std(self.noise_std)

    def apply(
        self, u: ArrayLike, observed: NDArray[np.bool_], rng: np.random.Generator | None = None
    ) -> NDArray[np.float32]:
        """:func:`observe` ``u`` on the mask ``observed`` (of this setting's node set) with this noise."""
        return observe(u, observed, self.noise_std, rng)
