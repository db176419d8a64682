r"""P1 finite elements on triangles (embedded in 3-D) and tetrahedra.

The monodomain diffusion term ``div(D grad u)`` is discretised with linear
elements and a lumped (row-sum) mass matrix, giving ``du/dt = -M^{-1} K u``.
Element diffusivity is the mean of its nodes' diffusivities. With fibres
(:attr:`shared.mesh.Mesh.fibres`) and an anisotropy ratio ``r = D_l / D_t``
the conductivity is a tensor per element,

.. math::

    D_e = d_e \left(\tfrac{1}{r} I + \left(1 - \tfrac{1}{r}\right) \overline{f f^T}\right),

``d_e`` the element diffusivity (the along-fibre value) and
:math:`\overline{f f^T}` the mean over the element's nodes of their fibres'
outer products (sign-free: ``f`` and ``-f`` give the same tensor; exact for
uniform fibres). On triangles only the fibres' component in the element's
plane counts, as the gradients lie in it. With sheets
(:attr:`shared.mesh.Mesh.sheets`) and a second ratio ``q = D_s / D_n`` of
conduction along the sheets and across them (orthotropic tissue), the sheet
normal conducts ``q`` times slower than the sheet:

.. math::

    D_e = d_e \left(\tfrac{1}{r q} I + \left(1 - \tfrac{1}{r q}\right) \overline{f f^T}
          + \left(\tfrac{1}{r} - \tfrac{1}{r q}\right) \overline{s s^T}\right).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from shared.errors import MeshError
from shared.mesh import Mesh

__all__ = [
    "Geometry",
    "element_gradients",
    "stiffness_matrix",
    "conductivity_tensors",
    "lumped_mass",
    "diffusion_operator",
    "operator_from",
]

#: ``element_gradients``' result; pass it on to assemble several matrices of one mesh from one pass over its cells.
Geometry = tuple[NDArray[np.float64], NDArray[np.float64]]


def element_gradients(points: NDArray[np.float64], cells: NDArray[np.integer]) -> Geometry:
    """Gradients of the P1 basis functions and the cell measures.

    Returns ``grads`` of shape (M, k, 3) (k = 3 or 4 nodes per cell) and the
    cell areas/volumes (M,). For triangles in 3-D the gradients lie in the
    triangle's plane.
    """
    p = points[cells]
    if cells.shape[1] == 3:
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        normal = np.cross(e1, e2)
        twice_area = np.linalg.norm(normal, axis=1)
        if np.any(twice_area <= 0):
            raise MeshError(f"{int(np.sum(twice_area <= 0))} degenerate triangle(s) (zero area)")
        n_hat = normal / twice_area[:, None]
        # grad(phi_i) = n x e_i / (2A), with e_i the edge opposite node i, oriented ccw.
        opposite = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
        grads = np.cross(n_hat[:, None, :], opposite) / twice_area[:, None, None]
        return grads, 0.5 * twice_area
    jac = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)  # (M,3,3)
    det = np.linalg.det(jac)
    if np.any(np.abs(det) <= 0):
        raise MeshError(f"{int(np.sum(np.abs(det) <= 0))} degenerate tetrahedra (zero volume)")
    inv = np.linalg.inv(jac)  # rows are gradients of the barycentric coordinates 1..3
    g123 = inv
    g0 = -g123.sum(axis=1, keepdims=True)
    return np.concatenate([g0, g123], axis=1), np.abs(det) / 6.0


def stiffness_matrix(
    mesh: Mesh,
    node_diffusivity: NDArray[np.float64],
    geometry: Geometry | None = None,
    anisotropy: float | None = None,
    sheet_anisotropy: float | None = None,
) -> sp.csr_matrix:
    """Symmetric stiffness matrix ``K_ij = sum_e |e| grad(phi_i) . D_e grad(phi_j)``.

    ``anisotropy``: ``D_l / D_t`` along the mesh's fibres, ``sheet_anisotropy``
    ``D_s / D_n`` along its sheets (module docstring); ``None`` or 1:
    isotropic, ``D_e = d_e I`` (the fibres are not read), and transversely
    isotropic about the fibres.
    """
    grads, measure = geometry or element_gradients(mesh.points, mesh.cells)
    d_cell = np.asarray(node_diffusivity, float)[mesh.cells].mean(axis=1)
    if (anisotropy or 1.0) == 1.0 and (sheet_anisotropy or 1.0) == 1.0:
        local = np.einsum("mid,mjd->mij", grads, grads)
    else:
        tensors = conductivity_tensors(mesh, anisotropy or 1.0, sheet_anisotropy or 1.0)
        local = np.einsum("mid,mde,mje->mij", grads, tensors, grads)
    local = local * (d_cell * measure)[:, None, None]
    k = mesh.cells.shape[1]
    rows = np.repeat(mesh.cells, k, axis=1).ravel()
    cols = np.tile(mesh.cells, (1, k)).ravel()
    n = mesh.n_nodes
    return sp.csr_matrix((local.ravel(), (rows, cols)), shape=(n, n))


def conductivity_tensors(mesh: Mesh, anisotropy: float, sheet_anisotropy: float = 1.0) -> NDArray[np.float64]:
    """(M, 3, 3) relative conductivity of each element: ``I / r + (1 - 1 / r)`` times the mean of its nodes'
    ``f f^T``, and with ``sheet_anisotropy`` ``q`` the sheets' term (module docstring)."""
    outer = _mean_outer(mesh, "fibres", "anisotropic conduction", "anisotropy", anisotropy, "D_l / D_t")
    if sheet_anisotropy == 1.0:
        return np.eye(3) / anisotropy + (1.0 - 1.0 / anisotropy) * outer
    sheets = _mean_outer(mesh, "sheets", "orthotropic conduction", "sheet_anisotropy", sheet_anisotropy, "D_s / D_n")
    normal = 1.0 / (anisotropy * sheet_anisotropy)
    return np.eye(3) * normal + (1.0 - normal) * outer + (1.0 / anisotropy - normal) * sheets


#: Where a mesh gets the directions each conduction setting needs.
_DIRECTION_SOURCES = {
    "fibres": "a mesh file's point data 'fibre', or rule-based fibres (--fibres; simgen.meshes.fibres.ldrb_fibres)",
    "sheets": "a mesh file's point data 'sheet', or rule-based ones (simgen.meshes.fibres.ldrb_frames)",
}


def _mean_outer(mesh: Mesh, kind: str, conduction: str, setting: str, ratio: float, meaning: str) -> NDArray:
    """(M, 3, 3) mean over each element's nodes of the outer products of the mesh's ``kind`` (``fibres`` or
    ``sheets``); :class:`MeshError` when the mesh has none or ``ratio`` (the ``setting``) is no ratio >= 1."""
    vectors = getattr(mesh, kind)
    if vectors is None:
        raise MeshError(
            f"mesh {mesh.name!r} has no {kind}: {conduction} ({setting} = {ratio:g}) needs them: "
            + _DIRECTION_SOURCES[kind]
        )
    if not np.isfinite(ratio) or ratio < 1.0:
        raise MeshError(f"{setting} {ratio!r} must be a finite ratio {meaning} >= 1")
    v = vectors[mesh.cells]  # (M, k, 3)
    return np.einsum("mki,mkj->mij", v, v) / mesh.cells.shape[1]


def lumped_mass(mesh: Mesh, geometry: Geometry | None = None) -> NDArray[np.float64]:
    """Row-sum lumped mass: each cell gives measure / k to each of its k nodes."""
    _, measure = geometry or element_gradients(mesh.points, mesh.cells)
    k = mesh.cells.shape[1]
    return np.bincount(mesh.cells.ravel(), weights=np.repeat(measure / k, k), minlength=mesh.n_nodes)


def diffusion_operator(
    mesh: Mesh,
    node_diffusivity: NDArray[np.float64],
    geometry: Geometry | None = None,
    anisotropy: float | None = None,
    sheet_anisotropy: float | None = None,
) -> sp.csr_matrix:
    """``A = -M^{-1} K`` so that the diffusion step reads ``du/dt = A u``."""
    geometry = geometry or element_gradients(mesh.points, mesh.cells)
    stiffness = stiffness_matrix(mesh, node_diffusivity, geometry, anisotropy, sheet_anisotropy)
    return operator_from(stiffness, lumped_mass(mesh, geometry))


def operator_from(stiffness: sp.spmatrix, mass: NDArray[np.float64]) -> sp.csr_matrix:
    """``A = -M^{-1} K`` from the stiffness matrix and the lumped mass (canonical CSR)."""
    A = -(sp.diags(1.0 / mass) @ stiffness).tocsr()
    A.sum_duplicates()
    A.sort_indices()
    return A
