"""A smooth reaction-diffusion problem with a float64 reference, for the integrators' order tests."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from scipy.linalg import eigh

from shared.fem import diffusion_operator, element_gradients, lumped_mass
from shared.mesh import Mesh
from simgen.meshes.slab import strip
from simgen.solver.cells.aliev_panfilov import APParams


class SmoothProblem(NamedTuple):
    """Strip, D = 1, k = 8, a = 0.15, v(0) = 0, u(0) = 0.5 + 0.3 x (a smooth diffusion eigenvector scaled to
    max 1): all above threshold, u rises smoothly to ~1 everywhere, no front. ``exact``: u at ``end`` from
    float64 DOP853."""

    mesh: Mesh
    A: sp.csr_matrix
    mass: NDArray[np.float64]
    a: float
    u0: NDArray[np.float64]
    end: float
    exact: NDArray[np.float64]


@pytest.fixture(scope="session")
def smooth_problem() -> SmoothProblem:
    mesh = strip(10.0, 1.0, 0.5)
    n, p, a = mesh.n_nodes, APParams(), 0.15
    A = diffusion_operator(mesh, np.ones(n))
    mass = lumped_mass(mesh, element_gradients(mesh.points, mesh.cells))
    s = np.sqrt(mass)
    _, vectors = eigh(-(sp.diags(s) @ A @ sp.diags(1 / s)).toarray())
    mode = vectors[:, 2] / s
    u0 = 0.5 + 0.3 * mode / np.abs(mode).max()

    def rhs(t, y):
        u, v = y[:n], y[n:]
        eps = p.eps0 + p.mu1 * v / (u + p.mu2)
        return np.concatenate([A @ u + p.k * u * (1 - u) * (u - a) - u * v, eps * (-v - p.k * u * (u - a - 1))])

    end = 1.2
    exact = solve_ivp(rhs, (0, end), np.concatenate([u0, np.zeros(n)]), "DOP853", rtol=1e-12, atol=1e-14).y[:n, -1]
    return SmoothProblem(mesh, A, mass, a, u0, end, exact)
