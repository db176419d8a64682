"""Real spherical harmonics of low degree, for smooth random shape perturbations.

The basis is orthonormal on the unit sphere (``integral Y_a Y_b dOmega = delta_ab``),
so a field ``sum_k c_k Y_k`` has root-mean-square ``|c| / sqrt(4 pi)`` over the sphere.
Coefficients are ordered by degree ``l = 2, 3, ...`` and, within a degree, by
order ``m = -l .. l`` (``m < 0``: ``sin(|m| phi)``, ``m > 0``: ``cos(m phi)``).
Degrees 0 and 1 (a change of size, a shift) are left out.
"""

from __future__ import annotations

from math import factorial

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError

__all__ = ["FIRST_DEGREE", "n_coefficients", "degree_of", "harmonic_field", "random_coefficients"]

#: Lowest degree of the perturbation basis.
FIRST_DEGREE = 2


def n_coefficients(max_degree: int) -> int:
    """Number of coefficients of the degrees ``FIRST_DEGREE .. max_degree``."""
    return (max_degree + 1) ** 2 - FIRST_DEGREE**2


def degree_of(n: int) -> int:
    """Highest degree of a complete set of ``n`` coefficients; :class:`MeshError` if none fits."""
    degree = int(round(np.sqrt(n + FIRST_DEGREE**2))) - 1
    if n <= 0 or n_coefficients(degree) != n:
        raise MeshError(
            f"{n} harmonic coefficients do not fill whole degrees {FIRST_DEGREE}..L "
            f"(valid counts: {[n_coefficients(d) for d in range(FIRST_DEGREE, 6)]}, ...)"
        )
    return degree


def _legendre(l: int, m: int, x: NDArray) -> NDArray:
    """Associated Legendre function ``P_l^m(x)`` (``m >= 0``, Condon-Shortley phase) by recurrence."""
    p_mm = (-1) ** m * np.prod(np.arange(1, 2 * m, 2), dtype=float) * (1 - x * x) ** (m / 2)
    if l == m:
        return p_mm
    p_prev, p = p_mm, x * (2 * m + 1) * p_mm
    for k in range(m + 2, l + 1):
        p_prev, p = p, ((2 * k - 1) * x * p - (k + m - 1) * p_prev) / (k - m)
    return p


def harmonic_field(coefficients: NDArray | tuple[float, ...], unit: NDArray) -> NDArray[np.float64]:
    """``sum_k c_k Y_k(u)`` at unit vectors ``unit`` (..., 3); zero for no coefficients."""
    coefficients = np.asarray(coefficients, dtype=np.float64)
    unit = np.asarray(unit, dtype=np.float64)
    out = np.zeros(unit.shape[:-1])
    if len(coefficients) == 0:
        return out
    x = np.clip(unit[..., 2], -1.0, 1.0)  # cosine of the polar angle
    azimuth = np.arctan2(unit[..., 1], unit[..., 0])
    k = 0
    for l in range(FIRST_DEGREE, degree_of(len(coefficients)) + 1):
        for m in range(-l, l + 1):
            norm = np.sqrt((2 * l + 1) / (4 * np.pi) * factorial(l - abs(m)) / factorial(l + abs(m)))
            if m == 0:
                angular = 1.0
            else:
                norm *= np.sqrt(2.0)
                angular = np.sin(-m * azimuth) if m < 0 else np.cos(m * azimuth)
            out += coefficients[k] * norm * _legendre(l, abs(m), x) * angular
            k += 1
    return out


def random_coefficients(rms: float, seed: int, max_degree: int) -> tuple[float, ...]:
    """Coefficients of a random field with root-mean-square ``rms`` over the sphere.

    Standard-normal draws from ``default_rng(seed)``, scaled by ``1 / (l - 1)``
    so that higher degrees (shorter wavelengths) are weaker, then normalised;
    ``()`` for ``rms = 0``.
    """
    if rms == 0:
        return ()
    degrees = np.concatenate([np.full(2 * l + 1, l) for l in range(FIRST_DEGREE, max_degree + 1)])
    c = np.random.default_rng(seed).standard_normal(len(degrees)) / (degrees - 1)
    return tuple((c * rms * np.sqrt(4 * np.pi) / np.linalg.norm(c)).tolist())
