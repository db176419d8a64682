"""The Aliev-Panfilov cell model (Aliev & Panfilov 1996), dimensionless.

.. math::

    \\partial_t u = \\nabla\\cdot(D\\nabla u) + k u (1-u)(u-a) - u v, \\qquad
    \\partial_t v = \\varepsilon(u, v)\\,(-v - k u (u - a - 1)),

with :math:`\\varepsilon = \\varepsilon_0 + \\mu_1 v / (u + \\mu_2)` (``"standard"``)
or a constant :math:`\\varepsilon` (``"simple"``, as used in personalisation work).
Physical read-out: ``V[mV] = 100 u - 80`` and ``t[ms] = 12.9 t``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError
from shared.tissue import front_speed
from shared.units import MS_PER_TIME_UNIT, to_millivolts
from simgen.solver.cells.ops import fma, register_rates

__all__ = ["APParams", "APConstants", "reaction", "front_speed", "MS_PER_TIME_UNIT", "to_millivolts"]


class APConstants(NamedTuple):
    """The kernels' constants (float32): 1, ``k``, ``eps0``, ``mu1``, ``mu2`` (``"simple"``: ``eps``, 0)."""

    one: np.float32
    k: np.float32
    eps0: np.float32
    mu1: np.float32
    mu2: np.float32


def rates(u, v, lap, a, c):
    """``(du/dt, dv/dt)`` with the diffusion term ``lap``; every product that is added is an explicit
    :func:`~simgen.solver.cells.ops.fma`, so numba's scalar and vector code round alike."""
    one, k, eps0, mu1, mu2 = c
    if lap is None:  # the reaction alone (IMEX): one rounding fewer than adding a zero diffusion term
        du = fma(k * u * (one - u), u - a, -(u * v))
    else:
        du = fma(-u, v, fma(k * u * (one - u), u - a, lap))
    eps = eps0 + mu1 * v / (u + mu2)
    return du, eps * fma(-(k * u), u - a - one, -v)


register_rates(APConstants, rates)


@dataclass(frozen=True)
class APParams:
    """Cell-model constants (Aliev & Panfilov 1996 defaults), in the model's time unit (12.9 ms)."""

    name: ClassVar[str] = "aliev-panfilov"
    title: ClassVar[str] = "Aliev-Panfilov (1996)"
    citation: ClassVar[str] = (
        "R. R. Aliev and A. V. Panfilov, *A simple two-variable model of cardiac excitation*, "
        "Chaos, Solitons & Fractals 7(3), 1996 (the cell model)."
    )
    equations: ClassVar[tuple[str, ...]] = (
        "du/dt = div(D grad u) + k u (1 - u)(u - a) - u v",
        "dv/dt = eps(u, v) (-v - k u (u - a - 1))",
        "eps(u, v) = eps0 + mu1 v / (u + mu2)   (variant 'standard'; 'simple': eps = eps_simple)",
    )
    #: ``v`` at rest.
    resting_v: ClassVar[float] = 0.0
    #: Largest time step (time units) at which the reaction is integrated accurately.
    dt_accuracy: ClassVar[float] = 0.05

    variant: Literal["standard", "simple"] = "standard"
    k: float = 8.0
    eps0: float = 0.002
    mu1: float = 0.2
    mu2: float = 0.3
    eps_simple: float = 0.01
    #: The model's name where a spec writes the default out (``cell = "aliev-panfilov"``); read as unset, so
    #: the spec keeps its meaning and hash.
    cell: Literal["aliev-panfilov"] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "cell", None)
        if self.variant not in ("standard", "simple"):
            raise InputError(f"unknown Aliev-Panfilov variant {self.variant!r} (use 'standard' or 'simple')")
        for name in ("k", "eps0", "mu2", "eps_simple"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"Aliev-Panfilov parameter {name}={value} must be finite and > 0")
        if not np.isfinite(self.mu1) or self.mu1 < 0:
            raise InputError(f"Aliev-Panfilov parameter mu1={self.mu1} must be finite and >= 0")

    def constants(self) -> APConstants:
        """The kernels' float32 constants; the ``"simple"`` variant is ``eps0 = eps_simple, mu1 = 0``."""
        eps0, mu1 = (self.eps_simple, 0.0) if self.variant == "simple" else (self.eps0, self.mu1)
        return APConstants(*map(np.float32, (1.0, self.k, eps0, mu1, self.mu2)))

    @property
    def max_rate(self) -> float:
        """A bound of the reaction's stiffness (per time unit): its slope in ``u`` on [0, 1], ``k (1 - a) < k``."""
        return self.k

    def front_speed(self, D: float, a: float) -> float:
        """Planar front speed (mm per time unit; recovery neglected): ``sqrt(2 k D)(1/2 - a)``."""
        return front_speed(D, a, self.k)

    def apd_scaled(self, scale: float) -> APParams:
        """The model with about ``scale`` times its action-potential duration: the recovery rates ``eps0``,
        ``mu1`` and ``eps_simple`` divided by ``scale`` (the upstroke and front speed unchanged)."""
        return replace(self, eps0=self.eps0 / scale, mu1=self.mu1 / scale, eps_simple=self.eps_simple / scale)

    def describe(self) -> str:
        """One line for a dataset card."""
        return f"Aliev-Panfilov model ({self.variant}, k = {self.k:g})"


def reaction(u: NDArray, v: NDArray, a: NDArray | float, p: APParams = APParams()) -> tuple[NDArray, NDArray]:
    """Right-hand sides of the cell model (without diffusion), in float64 NumPy."""
    du = p.k * u * (1.0 - u) * (u - a) - u * v
    eps = p.eps0 + p.mu1 * v / (u + p.mu2) if p.variant == "standard" else p.eps_simple
    dv = eps * (-v - p.k * u * (u - a - 1.0))
    return du, dv
