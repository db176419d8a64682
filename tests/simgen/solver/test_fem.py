"""P1 assembly: consistency properties with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from shared.errors import MeshError
from shared.fem import diffusion_operator, lumped_mass, stiffness_matrix
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.slab import slab, strip
from simgen.solver.timestep import largest_eigenvalue


@pytest.fixture(params=["strip", "slab", "lv-tri", "lv-tet"])
def mesh(request) -> Mesh:
    return {
        "strip": lambda: strip(3.0, 2.0, 0.5),
        "slab": lambda: slab(2.0, 1.5, 1.0, 0.5),
        "lv-tri": lambda: lv_ellipsoid(500, "triangle"),
        "lv-tet": lambda: lv_ellipsoid(500, "tetra"),
    }[request.param]()


def test_stiffness_symmetric_psd_with_constant_kernel(mesh):
    K = stiffness_matrix(mesh, np.ones(mesh.n_nodes))
    assert abs(K - K.T).max() < 1e-10
    np.testing.assert_allclose(K @ np.ones(mesh.n_nodes), 0.0, atol=1e-10)
    x = np.random.default_rng(0).normal(size=mesh.n_nodes)
    assert x @ (K @ x) > 0


def test_linear_field_is_harmonic_at_interior_nodes():
    m = slab(2.0, 2.0, 2.0, 0.5)
    K = stiffness_matrix(m, np.ones(m.n_nodes))
    interior = np.setdiff1d(np.arange(m.n_nodes), m.nodes("surface"))
    for axis in range(3):
        np.testing.assert_allclose((K @ m.points[:, axis])[interior], 0.0, atol=1e-12)


def test_energy_of_linear_field_equals_measure():
    """u = x has |grad u|^2 = 1, so u^T K u equals the area / volume."""
    m2, m3 = strip(3.0, 2.0, 0.5), slab(2.0, 1.5, 1.0, 0.5)
    for m, measure in [(m2, 6.0), (m3, 3.0)]:
        x = m.points[:, 0]
        assert x @ (stiffness_matrix(m, np.ones(m.n_nodes)) @ x) == pytest.approx(measure)
        assert lumped_mass(m).sum() == pytest.approx(measure)
    # Diffusivity scales the energy linearly.
    x = m2.points[:, 0]
    assert x @ (stiffness_matrix(m2, 2.5 * np.ones(m2.n_nodes)) @ x) == pytest.approx(15.0)


def test_largest_eigenvalue_matches_dense(mesh):
    A = diffusion_operator(mesh, np.ones(mesh.n_nodes))
    dense = np.linalg.eigvals(-A.toarray()).real.max()
    assert largest_eigenvalue(A, lumped_mass(mesh)) == pytest.approx(dense, rel=1e-3)


def test_degenerate_cell_is_refused():
    m = Mesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="degenerate"):
        stiffness_matrix(m, np.ones(3))


def test_operator_rows_sum_to_zero(mesh):
    A = diffusion_operator(mesh, np.linspace(0.1, 1.0, mesh.n_nodes))
    assert isinstance(A, sp.csr_matrix)
    np.testing.assert_allclose(A @ np.ones(mesh.n_nodes), 0.0, atol=1e-9)
