"""Real spherical harmonics: orthonormal basis, random fields of a given RMS."""

from __future__ import annotations

import numpy as np
import pytest

from shared.errors import MeshError
from simgen.meshes.harmonics import degree_of, harmonic_field, n_coefficients, random_coefficients


def sphere_quadrature(n_polar: int = 60, n_azimuth: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors and weights of a midpoint rule on the sphere (weights sum to ~4 pi)."""
    polar = (np.arange(n_polar) + 0.5) / n_polar * np.pi
    azimuth = np.arange(n_azimuth) / n_azimuth * 2 * np.pi
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    unit = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1)
    return unit.reshape(-1, 3), (np.sin(p) * (np.pi / n_polar) * (2 * np.pi / n_azimuth)).ravel()


def test_basis_is_orthonormal():
    unit, weight = sphere_quadrature()
    n = n_coefficients(4)
    basis = np.stack([harmonic_field(np.eye(n)[k], unit) for k in range(n)])
    gram = (basis * weight) @ basis.T
    np.testing.assert_allclose(gram, np.eye(n), atol=2e-3)


def test_random_field_has_the_requested_rms_and_is_seeded():
    unit, weight = sphere_quadrature()
    c = random_coefficients(2.5, seed=7, max_degree=4)
    assert len(c) == n_coefficients(4) == 21
    field = harmonic_field(c, unit)
    assert np.sqrt((field**2 * weight).sum() / (4 * np.pi)) == pytest.approx(2.5, rel=1e-3)
    assert c == random_coefficients(2.5, seed=7, max_degree=4)
    assert c != random_coefficients(2.5, seed=8, max_degree=4)
    assert random_coefficients(0.0, seed=7, max_degree=4) == ()
    np.testing.assert_array_equal(harmonic_field((), unit), 0.0)


def test_incomplete_degrees_are_refused():
    assert degree_of(5) == 2 and degree_of(12) == 3
    with pytest.raises(MeshError, match="do not fill whole degrees"):
        degree_of(6)
