"""The personalisation-baseline contract: fit simulator tissue parameters to context observations, then simulate.

A baseline maps a parameter vector ``x`` in a box to per-node tissue fields on
the subject's mesh (:meth:`PersonalisationBaseline.tissue_at`), and searches
that box with budgeted Bayesian optimisation for the fields whose simulation
of the context stimuli best matches what was observed:

.. math::

    f(x) = \\frac{1}{K T |O|} \\sum_{k, t} \\sum_{i \\in O}
           \\left(u_{kti}(x) - y_{kti}\\right)^2,

with ``O`` the observed nodes; from 12-lead ECGs ``y`` (K, 12, T) (``Observations.ecg``) the same mean over
leads and frames of the candidate's pseudo-ECG (its own tissue weighing the conductivity, through the
recording's electrodes) against ``y``, over the squared largest recorded value. One evaluation of ``f``
simulates all ``K`` context stimuli in one batched call of the simulator plug-in
(:mod:`shared.simulator`), so a budget counts simulator calls (candidates);
``FitResult.sequences`` also counts the simulated sequences (``K`` per call).
The simulator is reached only through its plug-in contract: ``learner`` never
imports ``simgen``.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from learner.baselines.bo import BOSettings, bayes_minimise
from learner.observations import Observations
from shared.ecg import PseudoECG, standard_electrodes
from shared.errors import InputError
from shared.mesh import Mesh
from shared.simulator import SimulatorPlugin, load_simulator
from shared.tissue import LABEL_BORDER, LABEL_CORE, LABEL_HEALTHY, TissueFields

__all__ = [
    "A_HEALTHY",
    "A_SCAR",
    "diffusivity_from_excitability",
    "fields_from_excitability",
    "FitResult",
    "PersonalisationBaseline",
]

#: Excitability of healthy tissue and of dense scar (the data's scar core).
A_HEALTHY, A_SCAR = 0.15, 0.5
#: Diffusivity scale at those two ends: scar also slows conduction, as in the data (core D = 0.1).
D_HEALTHY, D_SCAR = 1.0, 0.1


def diffusivity_from_excitability(a: ArrayLike) -> NDArray[np.float64]:
    """Diffusivity scale tied to excitability, linear from healthy to scar.

    .. math:: D(a) = D_h + (D_s - D_h) \\frac{a - a_h}{a_s - a_h},

    clipped to ``[D_s, D_h]`` = [0.1, 1] (``a_h = 0.15``, ``a_s = 0.5``).
    """
    a = np.asarray(a, dtype=np.float64)
    frac = np.clip((a - A_HEALTHY) / (A_SCAR - A_HEALTHY), 0.0, 1.0)
    return D_HEALTHY + (D_SCAR - D_HEALTHY) * frac


def fields_from_excitability(a: ArrayLike) -> TissueFields:
    """Tissue fields from a per-node excitability map: ``D`` from ``a``, labels by nearest material.

    A node is labelled scar core when ``a >= 0.4`` (nearer the core's 0.5 than
    the border's 0.3) and border zone when ``a >= 0.225``.
    """
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 1:
        raise InputError(f"an excitability map must be one value per node, got shape {a.shape}")
    label = np.full(a.shape, LABEL_HEALTHY, dtype=np.int8)
    label[a >= 0.225] = LABEL_BORDER
    label[a >= 0.4] = LABEL_CORE
    return TissueFields(a=a.copy(), D=diffusivity_from_excitability(a), label=label)


@dataclass(frozen=True)
class FitResult:
    """What a personalisation fit found and what it cost.

    Parameters
    ----------
    tissue : fitted per-node tissue fields.
    params : best parameter vector (d,) (per-region ``a`` or a VAE latent point).
    objective : context MSE at ``params``.
    history : context MSE of every simulator call, in order (length ``calls``).
    calls : simulator calls (candidates evaluated); equals the budget.
    sequences : sequences simulated (``calls`` x context size).
    seconds : wall time of the whole fit.
    setup_seconds : part of ``seconds`` spent before the search (regions, library, VAE).
    simulate_seconds : part of ``seconds`` spent inside the simulator.
    """

    tissue: TissueFields
    params: NDArray[np.float64]
    objective: float
    history: NDArray[np.float64]
    calls: int
    sequences: int
    seconds: float
    setup_seconds: float
    simulate_seconds: float

    @property
    def best_so_far(self) -> NDArray[np.float64]:
        """Running minimum of :attr:`history` (the convergence curve)."""
        return np.minimum.accumulate(self.history)


class PersonalisationBaseline(ABC):
    """Fit a parametrised tissue model to a subject's context observations by Bayesian optimisation.

    Subclasses say how many parameters there are (:attr:`dim`), prepare the
    parametrisation on a mesh (:meth:`_prepare`, returning the search box) and
    map a parameter vector to tissue fields (:meth:`tissue_at`).

    Parameters
    ----------
    budget : simulator calls per fit, initial design included.
    initial : Sobol initial design size; ``None`` means ``2 d + 1``.
    seed : seed of every random choice of a fit.
    restarts, raw_samples : acquisition optimiser settings.
    simulator : a backend name (``shared.simulator.load_simulator``) or a backend.
    """

    name: ClassVar[str] = "baseline"

    def __init__(
        self,
        *,
        budget: int = 100,
        initial: int | None = None,
        seed: int = 0,
        restarts: int = 8,
        raw_samples: int = 256,
        simulator: str | SimulatorPlugin = "aliev-panfilov",
    ) -> None:
        self.settings = BOSettings(budget, initial, restarts, raw_samples, seed)
        self.settings.initial_size(self.dim)  # refuse a budget below the initial design now, not mid-benchmark
        self.simulator = load_simulator(simulator) if isinstance(simulator, str) else simulator
        if not isinstance(self.simulator, SimulatorPlugin):
            raise InputError(f"simulator must be a backend name or implement simulate(), got {simulator!r}")
        self.result: FitResult | None = None
        self._mesh: Mesh | None = None
        self._solver: dict[str, Any] = {}

    @property
    @abstractmethod
    def dim(self) -> int:
        """Number of parameters searched."""

    @abstractmethod
    def _prepare(self, mesh: Mesh) -> NDArray[np.float64]:
        """Set up the parametrisation on ``mesh``; return the search box (2, dim)."""

    @abstractmethod
    def tissue_at(self, params: ArrayLike) -> TissueFields:
        """Tissue fields of parameter vector ``params`` on the prepared mesh."""

    def fit(self, observations: Observations, solver: Mapping[str, Any]) -> FitResult:
        """Search the tissue parameters that best reproduce the observed context; keep and return the fit.

        ``solver`` is the store's ``spec["solver"]`` table, so candidates are
        simulated exactly as the data were.
        """
        start = time.perf_counter()
        y, recorded = _check_observations(observations, solver)
        mesh, sites = observations.mesh, np.asarray(observations.sites, dtype=np.int64)
        solver = dict(solver)
        bounds = self._prepare(mesh)
        setup = time.perf_counter() - start
        spent = [0.0]

        def objective(params: NDArray[np.float64]) -> float:
            tissue = self.tissue_at(params)
            t0 = time.perf_counter()
            u = np.asarray(self.simulator.simulate(mesh, tissue, sites, solver))
            spent[0] += time.perf_counter() - t0
            expected = (len(sites), len(observations.times), mesh.n_nodes)
            if u.shape != expected:
                raise InputError(
                    f"the simulator returned shape {u.shape} but the observations need {expected}; "
                    "pass the solver table of the store the observations come from"
                )
            return float(np.mean((recorded(u.astype(np.float64), tissue) - y) ** 2))

        trace = bayes_minimise(objective, bounds, self.settings)
        best = trace.x[trace.best]
        self._mesh, self._solver = mesh, solver
        self.result = FitResult(
            tissue=self.tissue_at(best),
            params=best,
            objective=float(trace.f[trace.best]),
            history=trace.f,
            calls=len(trace.f),
            sequences=len(trace.f) * len(sites),
            seconds=time.perf_counter() - start,
            setup_seconds=setup,
            simulate_seconds=spent[0],
        )
        return self.result

    def predict(self, sites: Sequence[int] | NDArray[np.integer]) -> NDArray[np.float32]:
        """Simulate stimulation nodes ``sites`` with the fitted tissue: ``(S, T, N)`` float32."""
        if self.result is None or self._mesh is None:
            raise InputError(f"{type(self).__name__} has not been fitted: call fit() before predict()")
        s = np.asarray(sites)
        n = self._mesh.n_nodes
        if s.ndim != 1 or s.size == 0 or not np.issubdtype(s.dtype, np.integer):
            raise InputError(f"sites must be a non-empty 1-D list of node ids, got {sites!r}")
        bad = s[(s < 0) | (s >= n)]
        if bad.size:
            raise InputError(f"stimulation nodes {bad.tolist()} are not nodes of the {n}-node mesh")
        u = self.simulator.simulate(self._mesh, self.result.tissue, s.astype(np.int64), self._solver)
        return np.asarray(u, dtype=np.float32)

    def _repr_fields(self) -> dict[str, Any]:
        return {"budget": self.settings.budget, "seed": self.settings.seed}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._repr_fields().items())
        return f"{type(self).__name__}({args})"


Recorder = Callable[[NDArray[np.float64], TissueFields], NDArray[np.float64]]


def _check_observations(observations: Observations, solver: Mapping[str, Any]) -> tuple[NDArray[np.float64], Recorder]:
    """What the fit matches, and how a candidate's simulations (K, T, N) of given tissue are recorded like it:
    observed values (K, T, |O|) as float64 or ECGs (K, 12, T) over their largest value; refuses what a fit
    cannot use."""
    if not isinstance(observations, Observations):
        raise InputError(f"observations must be learner.observations.Observations, got {type(observations).__name__}")
    if not isinstance(solver, Mapping):
        raise InputError(f"solver must be the store's solver table (a mapping), got {type(solver).__name__}")
    _check_times(observations.times, solver)
    if observations.ecg is not None:
        mesh = observations.mesh
        electrodes = observations.electrodes or standard_electrodes(mesh)
        scale = float(np.abs(observations.ecg).max()) or 1.0

        def ecg(u: NDArray[np.float64], tissue: TissueFields) -> NDArray[np.float64]:
            lead_matrix = PseudoECG.assemble(mesh, electrodes, tissue.D).lead_matrix()
            return np.swapaxes(u @ lead_matrix.T, -1, -2) / scale

        return observations.ecg.astype(np.float64) / scale, ecg
    obs = np.asarray(observations.obs)
    observed = np.asarray(observations.observed, dtype=bool)
    if obs.ndim != 3 or obs.shape[0] < 1 or obs.shape[1] < 1:
        raise InputError(f"observations must be (K >= 1, T >= 1, N) sequences, got shape {obs.shape}")
    if observed.shape != (obs.shape[2],) or not observed.any():
        raise InputError("no node is observed: the observation mask must select at least one mesh node")
    y = obs[:, :, observed].astype(np.float64)
    if not np.isfinite(y).all():
        raise InputError("observations contain NaN or inf at observed nodes")
    return y, lambda u, tissue: u[:, :, observed]


def _check_times(times: NDArray, solver: Mapping[str, Any]) -> None:
    """Refuse recordings whose frame times are not the solver's."""
    count = len(times)
    frames, interval = solver.get("frames"), solver.get("output_interval")
    if frames is not None and int(frames) != count:
        raise InputError(f"the solver table simulates {frames} frames but the observations have {count}")
    if interval is not None and frames is not None:
        expected = float(interval) * np.arange(1, int(frames) + 1)
        if not np.allclose(np.asarray(times, float), expected, rtol=1e-6, atol=1e-9):
            raise InputError(
                f"observation times do not match the solver's frames (every {interval} time units from {interval})"
            )
