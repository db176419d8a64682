"""The methods a benchmark compares, by name: the trained surrogates (metaPNS, PNS) and the BO baselines.

Each name maps to a builder that makes a fresh :class:`~learner.evaluate.Method` from a
:class:`MethodContext`; :func:`register` adds one, :func:`build_methods` makes several.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from torch import Tensor

from learner.baselines import FSBO, VAEBO, PersonalisationBaseline
from learner.data.episodes import Episode
from learner.evaluate import Method, NeuralMethod
from learner.graph.hierarchy import MeshHierarchy
from learner.models.surrogate import PNS
from learner.observations import Observations
from shared.errors import ConfigError
from shared.mesh import Mesh

__all__ = ["MethodContext", "BaselineMethod", "METHODS", "NEURAL", "BASELINES", "register", "build_methods"]


@dataclass(frozen=True)
class MethodContext:
    """What a method's builder may need: trained models by name, and the store and budget the baselines run on."""

    models: dict[str, PNS] = field(default_factory=dict)
    solver: dict = field(default_factory=dict)  # the store's solver settings: the baselines simulate with them
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    budget: int = 100
    regions: int = 7
    seed: int = 0


class BaselineMethod(Method):
    """A BO baseline behind the :class:`~learner.evaluate.Method` interface (simulates its predictions)."""

    def __init__(self, baseline: PersonalisationBaseline, solver: dict, times: np.ndarray) -> None:
        self.baseline, self.solver, self.times, self.name = baseline, solver, times, baseline.name

    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        sites, subject = episode.context_sites.numpy(), episode.subject_id
        if episode.context_ecg is not None:  # through the standard electrodes, as the episode recorded them
            nobody = np.zeros(mesh.n_nodes, bool)
            obs = Observations(mesh, sites, None, nobody, self.times, subject, ecg=episode.context_ecg.numpy())
        else:
            obs = Observations(mesh, sites, episode.context_obs.numpy(), episode.observed.numpy(), self.times, subject)
        result = self.baseline.fit(obs, self.solver)
        return {"fit_s": result.seconds, "calls": float(result.calls)}

    def predict(self, sites: Tensor) -> np.ndarray:
        return self.baseline.predict(sites.numpy())


#: Method name -> builder of a fresh method.
METHODS: dict[str, Callable[[MethodContext], Method]] = {}
#: The trained surrogates and the BO baselines among :data:`METHODS`.
NEURAL = ("metaPNS", "PNS")
BASELINES = ("fs-bo", "vae-bo")


def register(name: str) -> Callable[[Callable[[MethodContext], Method]], Callable[[MethodContext], Method]]:
    """Decorator: make ``builder`` the method named ``name``."""

    def add(builder: Callable[[MethodContext], Method]) -> Callable[[MethodContext], Method]:
        METHODS[name] = builder
        return builder

    return add


@register("metaPNS")
def _metapns(context: MethodContext) -> Method:
    return NeuralMethod(context.models["metaPNS"], "metaPNS")


@register("PNS")
def _pns(context: MethodContext) -> Method:
    return NeuralMethod(context.models["PNS"], "PNS")


@register("fs-bo")
def _fs_bo(context: MethodContext) -> Method:
    baseline = FSBO(regions=context.regions, budget=context.budget, seed=context.seed)
    return BaselineMethod(baseline, context.solver, context.times)


@register("vae-bo")
def _vae_bo(context: MethodContext) -> Method:
    return BaselineMethod(VAEBO(budget=context.budget, seed=context.seed), context.solver, context.times)


def build_methods(names: tuple[str, ...], context: MethodContext, among: tuple[str, ...] | None = None) -> list[Method]:
    """Fresh methods ``names``, each from its registered builder; ``among``: the names allowed (default: all)."""
    allowed = tuple(METHODS) if among is None else among
    unknown = sorted(set(names) - set(allowed))
    if unknown:
        kind = "baseline(s)" if among == BASELINES else "method(s)"
        raise ConfigError(f"unknown {kind} {unknown}; choose from {sorted(allowed)}")
    return [METHODS[name](context) for name in names]
