"""Budgeted Bayesian minimisation of an expensive function over a box (botorch).

The loop both personalisation baselines share: a scrambled-Sobol initial
design, then one candidate per step chosen by maximising log expected
improvement under a Gaussian-process surrogate,

.. math::

    x_{n+1} = \\arg\\max_x \\log \\mathrm{EI}_n(x), \\qquad
    \\mathrm{EI}_n(x) = \\mathbb{E}\\left[\\max(g(x) - g^*_n, 0)\\right],

with :math:`g = -\\log f` modelled by a ``SingleTaskGP`` on inputs scaled to
the unit cube and standardised outputs. The GP sees :math:`-\\log f` because
the fitting error of a simulation spans orders of magnitude near its optimum.
Exactly ``budget`` evaluations of ``f`` are made; all random choices come from
``seed``, so a run is reproducible (torch's global generator is left as it was).
The GP work runs on one torch thread (:mod:`learner.baselines.threads`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from botorch.acquisition import LogExpectedImprovement
from botorch.exceptions.warnings import OptimizationWarning
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms.outcome import Standardize
from botorch.optim import optimize_acqf
from gpytorch.mlls import ExactMarginalLogLikelihood
from numpy.typing import ArrayLike, NDArray

from learner.baselines.threads import torch_threads
from shared.errors import InputError

__all__ = ["BOSettings", "BOTrace", "bayes_minimise"]

#: Floor added to ``f`` before the log, so an exact fit (f = 0) stays finite.
LOG_FLOOR = 1e-12


@dataclass(frozen=True)
class BOSettings:
    """How a Bayesian optimisation run spends its evaluations.

    Parameters
    ----------
    budget : total evaluations of the objective, initial design included.
    initial : Sobol initial design size; ``None`` means ``2 d + 1``.
    restarts, raw_samples : acquisition optimiser settings (``optimize_acqf``).
    seed : seed of the Sobol design and of the acquisition optimiser.
    """

    budget: int = 100
    initial: int | None = None
    restarts: int = 8
    raw_samples: int = 256
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("budget", "restarts", "raw_samples", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InputError(f"{name} must be an integer, got {value!r}")
        if self.budget < 1:
            raise InputError(f"budget must be >= 1 simulator call, got {self.budget}")
        if self.initial is not None:
            if isinstance(self.initial, bool) or not isinstance(self.initial, (int, np.integer)) or self.initial < 1:
                raise InputError(f"initial design size must be an integer >= 1, got {self.initial!r}")
            if self.budget < self.initial:
                raise InputError(f"budget ({self.budget}) is smaller than the initial design ({self.initial})")
        if self.restarts < 1 or self.raw_samples < 1:
            raise InputError(f"restarts and raw_samples must be >= 1, got {self.restarts}, {self.raw_samples}")
        if self.seed < 0:
            raise InputError(f"seed must be >= 0, got {self.seed}")

    def initial_size(self, dim: int) -> int:
        """Size of the initial design in ``dim`` dimensions; refuses a budget below it."""
        n = 2 * dim + 1 if self.initial is None else int(self.initial)
        if self.budget < n:
            raise InputError(
                f"budget ({self.budget}) is smaller than the initial design ({n} points for {dim} parameters); "
                f"raise the budget to at least {n} or set a smaller initial design"
            )
        return n


@dataclass(frozen=True)
class BOTrace:
    """Every evaluation of a run, in order: points ``x`` (n, d) and values ``f`` (n,)."""

    x: NDArray[np.float64]
    f: NDArray[np.float64]

    @property
    def best(self) -> int:
        """Index of the lowest value (the first one on ties)."""
        return int(np.argmin(self.f))


def bayes_minimise(
    f: Callable[[NDArray[np.float64]], float], bounds: ArrayLike, settings: BOSettings | None = None
) -> BOTrace:
    """Minimise ``f`` over the box ``bounds`` (2, d) with exactly ``settings.budget`` evaluations.

    ``f`` takes a point (d,) inside the box and returns a finite value >= 0.
    """
    settings = settings or BOSettings()
    box = np.asarray(bounds, dtype=np.float64)
    if box.ndim != 2 or box.shape[0] != 2 or box.shape[1] < 1:
        raise InputError(f"bounds must have shape (2, d) with d >= 1, got {box.shape}")
    if not (np.isfinite(box).all() and (box[1] > box[0]).all()):
        raise InputError(f"bounds must be finite with lower < upper, got {box.tolist()}")
    dim = box.shape[1]
    n_init = settings.initial_size(dim)
    unit = torch.stack([torch.zeros(dim), torch.ones(dim)]).double()

    xs: list[NDArray[np.float64]] = []
    fs: list[float] = []

    def evaluate(u: NDArray[np.float64]) -> None:
        u = np.clip(u, 0.0, 1.0)
        x = box[0] + u * (box[1] - box[0])
        value = float(f(x))
        if not np.isfinite(value) or value < 0:
            raise InputError(f"the objective returned {value!r} at {x.tolist()}; it must be finite and >= 0")
        xs.append(u)
        fs.append(value)

    with torch.random.fork_rng(), warnings.catch_warnings():
        torch.manual_seed(settings.seed)
        # L-BFGS often stops "ABNORMAL" on a flat acquisition surface; botorch then retries from
        # new starting points itself and reports each retry as a warning, noise in a benchmark log
        warnings.simplefilter("ignore", OptimizationWarning)
        warnings.filterwarnings("ignore", message="Optimization failed in `gen_candidates_scipy`")
        sobol = torch.quasirandom.SobolEngine(dim, scramble=True, seed=settings.seed)
        for u in sobol.draw(n_init, dtype=torch.float64).numpy():
            evaluate(u)
        while len(fs) < settings.budget:
            # per step: a numba simulator resets the OpenMP thread count that torch reads
            with torch_threads(1):
                train_x = torch.from_numpy(np.stack(xs))
                train_y = -torch.log(torch.tensor(fs, dtype=torch.float64) + LOG_FLOOR).unsqueeze(-1)
                model = SingleTaskGP(train_x, train_y, outcome_transform=Standardize(m=1))
                fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
                acq = LogExpectedImprovement(model, best_f=train_y.max())
                cand, _ = optimize_acqf(
                    acq, bounds=unit, q=1, num_restarts=settings.restarts, raw_samples=settings.raw_samples
                )
            evaluate(cand.detach().squeeze(0).numpy())
    x = box[0] + np.stack(xs) * (box[1] - box[0])
    return BOTrace(x=x, f=np.asarray(fs, dtype=np.float64))
