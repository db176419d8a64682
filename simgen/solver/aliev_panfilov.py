"""The Aliev-Panfilov cell model (Aliev & Panfilov 1996), dimensionless.

.. math::

    \\partial_t u = \\nabla\\cdot(D\\nabla u) + k u (1-u)(u-a) - u v, \\qquad
    \\partial_t v = \\varepsilon(u, v)\\,(-v - k u (u - a - 1)),

with :math:`\\varepsilon = \\varepsilon_0 + \\mu_1 v / (u + \\mu_2)` (``"standard"``)
or a constant :math:`\\varepsilon` (``"simple"``, as used in personalisation work).
Physical read-out: ``V[mV] = 100 u - 80`` and ``t[ms] = 12.9 t``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError
from shared.units import MS_PER_TIME_UNIT, to_millivolts

__all__ = ["APParams", "reaction", "front_speed", "MS_PER_TIME_UNIT", "to_millivolts"]


@dataclass(frozen=True)
class APParams:
    """Cell-model constants (Aliev & Panfilov 1996 defaults)."""

    variant: Literal["standard", "simple"] = "standard"
    k: float = 8.0
    eps0: float = 0.002
    mu1: float = 0.2
    mu2: float = 0.3
    eps_simple: float = 0.01

    def __post_init__(self) -> None:
        if self.variant not in ("standard", "simple"):
            raise InputError(f"unknown Aliev-Panfilov variant {self.variant!r} (use 'standard' or 'simple')")
        for name in ("k", "eps0", "mu2", "eps_simple"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"Aliev-Panfilov parameter {name}={value} must be finite and > 0")
        if not np.isfinite(self.mu1) or self.mu1 < 0:
            raise InputError(f"Aliev-Panfilov parameter mu1={self.mu1} must be finite and >= 0")


def reaction(u: NDArray, v: NDArray, a: NDArray | float, p: APParams = APParams()) -> tuple[NDArray, NDArray]:
    """Right-hand sides of the cell model (without diffusion)."""
    du = p.k * u * (1.0 - u) * (u - a) - u * v
    eps = p.eps0 + p.mu1 * v / (u + p.mu2) if p.variant == "standard" else p.eps_simple
    dv = eps * (-v - p.k * u * (u - a - 1.0))
    return du, dv


def front_speed(D: float, a: float, k: float = 8.0) -> float:
    """Planar front speed of the excitation (recovery neglected): ``sqrt(2kD)(1/2 - a)``."""
    return float(np.sqrt(2.0 * k * D) * (0.5 - a))
