"""Rule-based myocardial fibres on a left-ventricular volume mesh (the LDRB rule of Bayer et al. 2012, LV part).

Two P1 Laplace solves on the mesh (:func:`laplace`, the project's own
stiffness matrix, Dirichlet values by elimination):

- the transmural coordinate ``d``: 0 on the endocardium, 1 on the epicardium;
- the apico-basal coordinate ``psi``: 0 at the apex, 1 on the base.

At each node (gradients of the elements around it, volume-weighted) the
transmural direction ``e_t = grad d / |grad d|``, the longitudinal direction
``e_l``, the part of ``grad psi`` orthogonal to ``e_t``, and the
circumferential direction ``e_c = e_l x e_t`` make a right-handed frame
``(e_c, e_l, e_t)``. The fibre turns from ``e_c`` towards ``e_l`` by the helix
angle, linear through the wall,

.. math:: \\alpha(d) = \\alpha_{endo} (1 - d) + \\alpha_{epi} d, \\qquad f = \\cos\\alpha\\, e_c + \\sin\\alpha\\, e_l,

(+60 degrees at the endocardium to -60 at the epicardium by default: seen from
outside, counter-clockwise from the circumferential direction is positive).
Fibres are unit vectors orthogonal to ``e_t``, so tangent to both surfaces.
The biventricular rule (separate LV and RV solves blended across the septum)
is not done: meshes with an RV endocardium are refused.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import spsolve

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.solver.fem import element_gradients, stiffness_matrix

__all__ = ["HELIX_ENDO", "HELIX_EPI", "laplace", "node_gradients", "ldrb_fibres"]

#: Default helix angles (degrees) at the endocardium and the epicardium.
HELIX_ENDO, HELIX_EPI = 60.0, -60.0


def laplace(mesh: Mesh, values: dict[float, NDArray[np.integer]]) -> NDArray[np.float64]:
    """The P1 solution of Laplace's equation on ``mesh`` taking ``values`` (value -> node ids) on those nodes."""
    K = stiffness_matrix(mesh, np.ones(mesh.n_nodes)).tocsr()
    fixed = np.zeros(mesh.n_nodes, bool)
    u = np.zeros(mesh.n_nodes)
    for value, nodes in values.items():
        fixed[nodes], u[nodes] = True, value
    free = ~fixed
    rhs = -K[free][:, fixed] @ u[fixed]
    u[free] = spsolve(sp.csc_matrix(K[free][:, free]), rhs)
    return u


def node_gradients(mesh: Mesh, values: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) gradient of the P1 field ``values`` at each node: its elements' gradients, measure-weighted."""
    grads, measure = element_gradients(mesh.points, mesh.cells)
    cell_grad = np.einsum("mk,mkd->md", values[mesh.cells], grads) * measure[:, None]
    k = mesh.cells.shape[1]
    total = np.zeros((mesh.n_nodes, 3))
    np.add.at(total, mesh.cells.ravel(), np.repeat(cell_grad, k, axis=0))
    weight = np.bincount(mesh.cells.ravel(), weights=np.repeat(measure, k), minlength=mesh.n_nodes)
    return total / weight[:, None]


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def ldrb_fibres(
    mesh: Mesh, helix_endo: float = HELIX_ENDO, helix_epi: float = HELIX_EPI
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fibres (N, 3) and the transmural coordinate ``d`` (N,) of an LV volume mesh (module docstring).

    Needs a tetrahedral mesh with ``endocardium``, ``epicardium`` and ``base``
    node sets and a long axis (:attr:`shared.mesh.Mesh.axis`, whose apex
    point fixes the apex nodes); :class:`MeshError` names what is missing.
    """
    if mesh.cell_type != "tetra":
        raise MeshError(f"mesh {mesh.name!r}: rule-based fibres need a volume (tetrahedral) mesh")
    if "rv_endocardium" in mesh.node_sets:
        raise MeshError(f"mesh {mesh.name!r}: rule-based fibres of a biventricle (the LDRB septum blend) are not done")
    if mesh.axis is None:
        raise MeshError(f"mesh {mesh.name!r}: rule-based fibres need its long axis (apex and base)")
    endo, epi, base = (mesh.nodes(name) for name in ("endocardium", "epicardium", "base"))
    d = laplace(mesh, {0.0: endo, 1.0: epi})
    length = np.linalg.norm(np.asarray(mesh.axis.base) - np.asarray(mesh.axis.apex))
    apex = np.flatnonzero(np.linalg.norm(mesh.points - mesh.axis.apex, axis=1) <= 0.05 * length)
    if not apex.size:
        apex = np.array([int(np.argmin(np.linalg.norm(mesh.points - mesh.axis.apex, axis=1)))])
    psi = laplace(mesh, {0.0: apex, 1.0: base})
    e_t = _unit(node_gradients(mesh, d))
    g = node_gradients(mesh, psi)
    axis = np.asarray(mesh.axis.base, float) - np.asarray(mesh.axis.apex, float)
    flat = np.linalg.norm(g, axis=1) < 1e-9 * np.abs(g).max()  # at the apex nodes: the long axis instead
    g[flat] = axis / np.linalg.norm(axis)
    e_l = g - np.einsum("nd,nd->n", g, e_t)[:, None] * e_t
    along = np.linalg.norm(e_l, axis=1) < 1e-6  # grad psi along e_t (the apex): any tangent direction
    e_l[along] = np.cross(e_t[along], np.eye(3)[np.argmin(np.abs(e_t[along]), axis=1)])
    e_l = _unit(e_l)
    e_c = np.cross(e_l, e_t)
    alpha = np.radians(helix_endo * (1.0 - d) + helix_epi * d)[:, None]
    return _unit(np.cos(alpha) * e_c + np.sin(alpha) * e_l), d
