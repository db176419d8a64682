"""Rule-based myocardial fibres on ventricular volume meshes: the LDRB rule of Bayer et al. (2012).

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
On a biventricle (node sets ``lv_endocardium`` and ``rv_endocardium``) the
rule is Bayer et al.'s: the LV frame (from the LV endocardium's solve) and the
RV frame (from the RV's), each at the septal helix angle, are blended by the
RV share ``phi_rv / (phi_lv + phi_rv)`` and the result with the epicardial
frame by ``d``, each blend a bidirectional spherical interpolation of the
frames' quaternions (:func:`_bislerp`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import spsolve

from shared.errors import MeshError
from shared.fem import element_gradients, stiffness_matrix
from shared.mesh import Mesh

__all__ = [
    "HELIX_ENDO",
    "HELIX_EPI",
    "laplace",
    "node_gradients",
    "ventricular_coordinates",
    "rotational_coordinate",
    "SHEET_ENDO",
    "SHEET_EPI",
    "Frames",
    "ldrb_frames",
    "ldrb_fibres",
    "with_rule_fibres",
]

#: Default helix angles (degrees) at the endocardium and the epicardium.
HELIX_ENDO, HELIX_EPI = 60.0, -60.0
#: Default sheet angles (degrees) at the endocardium and the epicardium (Bayer et al. 2012).
SHEET_ENDO, SHEET_EPI = -65.0, 25.0


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


def _frames(mesh: Mesh, transmural: NDArray[np.float64], longitudinal: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3, 3) rotations whose columns are ``(e_c, e_l, e_t)``: ``e_t`` along ``transmural``, ``e_l`` the
    part of ``longitudinal`` orthogonal to it, ``e_c = e_l x e_t`` (module docstring). Where a gradient
    vanishes (the apex, a cavity's rim) the long axis or any orthogonal direction stands in."""
    axis = np.asarray(mesh.axis.base, float) - np.asarray(mesh.axis.apex, float)
    axis /= np.linalg.norm(axis)
    t, g = transmural.copy(), longitudinal.copy()
    for v, fallback in ((t, np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])), (g, axis)):
        flat = np.linalg.norm(v, axis=1) <= 1e-9 * np.abs(v).max()
        v[flat] = fallback
    e_t = _unit(t)
    e_l = g - np.einsum("nd,nd->n", g, e_t)[:, None] * e_t
    along = np.linalg.norm(e_l, axis=1) < 1e-6  # the longitudinal gradient along e_t: any tangent direction
    e_l[along] = np.cross(e_t[along], np.eye(3)[np.argmin(np.abs(e_t[along]), axis=1)])
    e_l = _unit(e_l)
    return np.stack([np.cross(e_l, e_t), e_l, e_t], axis=2)


def _rotated(frames: NDArray[np.float64], degrees: NDArray[np.float64]) -> NDArray[np.float64]:
    """``frames`` turned about their ``e_t`` by ``degrees``: ``e_c`` towards ``e_l``."""
    a = np.radians(degrees)[:, None]
    e_c, e_l = frames[:, :, 0], frames[:, :, 1]
    return np.stack([np.cos(a) * e_c + np.sin(a) * e_l, np.cos(a) * e_l - np.sin(a) * e_c, frames[:, :, 2]], axis=2)


def _quaternions(frames: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 4) unit quaternions ``(w, x, y, z)`` of rotation matrices (N, 3, 3)."""
    m = frames
    diagonal = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    w = np.sqrt(np.maximum(0.0, 1.0 + diagonal.sum(axis=1))) / 2
    signs = np.array([[1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    xyz = np.sqrt(np.maximum(0.0, 1.0 + diagonal @ signs.T)) / 2
    xyz = np.copysign(xyz, np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], 1))
    return _unit(np.column_stack([w, xyz]))


def _matrices(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3, 3) rotation matrices of unit quaternions (N, 4)."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )


def _times(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternion products ``a b`` (rows)."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.column_stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _bislerp(a: NDArray[np.float64], b: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bayer et al.'s bidirectional spherical interpolation from frames ``a`` (t = 0) to ``b`` (t = 1).

    A frame turned by 180 degrees about any of its axes describes the same fibres (they are axial), so of
    ``a``'s four such turns the one nearest ``b`` is interpolated along the great circle to ``b``.
    """
    qa, qb = _quaternions(a), _quaternions(b)
    turns = [_times(qa, np.tile(unit, (len(qa), 1))) for unit in np.eye(4)]  # qa * {1, i, j, k}
    dots = np.stack([np.einsum("nd,nd->n", q, qb) for q in turns], axis=1)
    best = np.argmax(np.abs(dots), axis=1)
    q = np.stack(turns, axis=1)[np.arange(len(qa)), best] * np.sign(dots[np.arange(len(qa)), best])[:, None]
    cos = np.clip(np.einsum("nd,nd->n", q, qb), -1.0, 1.0)
    theta = np.arccos(cos)[:, None]
    t = np.clip(t, 0.0, 1.0)[:, None]
    small = theta[:, 0] < 1e-6
    sin = np.where(small[:, None], 1.0, np.sin(theta))
    mixed = (np.sin((1 - t) * theta) * q + np.sin(t * theta) * qb) / sin
    mixed[small] = ((1 - t) * q + t * qb)[small]
    return _matrices(_unit(mixed))


def _apex_nodes(mesh: Mesh) -> NDArray[np.int64]:
    length = np.linalg.norm(np.asarray(mesh.axis.base) - np.asarray(mesh.axis.apex))
    apex = np.flatnonzero(np.linalg.norm(mesh.points - mesh.axis.apex, axis=1) <= 0.05 * length)
    return apex if apex.size else np.array([int(np.argmin(np.linalg.norm(mesh.points - mesh.axis.apex, axis=1)))])


class _Solves(NamedTuple):
    """The Laplace solutions of the rule: transmural, apico-basal, and on a biventricle the LV's and RV's."""

    transmural: NDArray[np.float64]
    apicobasal: NDArray[np.float64]
    lv: NDArray[np.float64] | None = None
    rv: NDArray[np.float64] | None = None

    @property
    def rv_share(self) -> NDArray[np.float64]:
        """0 on the LV endocardium, 1 on the RV's: ``phi_rv / (phi_lv + phi_rv)``."""
        return self.rv / np.maximum(self.lv + self.rv, 1e-12)


def _solves(mesh: Mesh) -> _Solves:
    if mesh.cell_type != "tetra":
        raise MeshError(f"mesh {mesh.name!r}: rule-based fibres need a volume (tetrahedral) mesh")
    if mesh.axis is None:
        raise MeshError(f"mesh {mesh.name!r}: rule-based fibres need its long axis (apex and base)")
    epi = mesh.nodes("epicardium")
    apicobasal = laplace(mesh, {0.0: _apex_nodes(mesh), 1.0: mesh.nodes("base")})
    if "rv_endocardium" not in mesh.node_sets:
        return _Solves(laplace(mesh, {0.0: mesh.nodes("endocardium"), 1.0: epi}), apicobasal)
    lv, rv = mesh.nodes("lv_endocardium"), mesh.nodes("rv_endocardium")
    return _Solves(
        laplace(mesh, {0.0: np.union1d(lv, rv), 1.0: epi}),
        apicobasal,
        laplace(mesh, {1.0: lv, 0.0: np.union1d(rv, epi)}),
        laplace(mesh, {1.0: rv, 0.0: np.union1d(lv, epi)}),
    )


def _coordinates(solves: _Solves) -> dict[str, NDArray[np.float64]]:
    found = {"transmural": solves.transmural, "apicobasal": solves.apicobasal}
    return found if solves.lv is None else {**found, "rv_share": solves.rv_share}


def ventricular_coordinates(mesh: Mesh) -> dict[str, NDArray[np.float64]]:
    """The Laplace coordinates the rule builds on, per node: ``transmural`` (0 endocardium, 1 epicardium),
    ``apicobasal`` (0 apex, 1 base) and, on a biventricle, ``rv_share`` (0 on the LV endocardium, 1 on the
    RV's); and the ``rotational`` coordinate (:func:`rotational_coordinate`).

    Needs a tetrahedral mesh with ``endocardium`` (an LV) or ``lv_endocardium``
    and ``rv_endocardium`` (a biventricle), ``epicardium`` and ``base`` node
    sets and a long axis (:attr:`shared.mesh.Mesh.axis`, whose apex point fixes
    the apex nodes); :class:`MeshError` names what is missing.
    """
    return {**_coordinates(_solves(mesh)), "rotational": rotational_coordinate(mesh)}


def rotational_coordinate(mesh: Mesh) -> NDArray[np.float64]:
    """Angle (radians, in (-pi, pi]) of each node around the long axis, 0 along the axis's reference direction.

    As the rotational coordinate of universal ventricular coordinates: 0
    towards the RV (the reference of a detected BiV axis points to the RV
    cavity's centre, the septum's landmark of a given one), growing
    counter-clockwise seen from the base, the sign of the AHA angle of
    :func:`simgen.meshes.aha.longitudinal_angular`. Needs the long axis.
    """
    if mesh.axis is None:
        raise MeshError(f"mesh {mesh.name!r}: the rotational coordinate needs its long axis (apex and base)")
    d = mesh.axis.direction
    r = np.asarray(mesh.axis.reference, dtype=np.float64)
    r = r - (r @ d) * d
    if np.linalg.norm(r) < 1e-9:
        raise MeshError(f"mesh {mesh.name!r}: axis reference is parallel to the long axis")
    r /= np.linalg.norm(r)
    x = mesh.points - np.asarray(mesh.axis.apex, dtype=np.float64)
    return np.arctan2(x @ np.cross(d, r), x @ r)


class Frames(NamedTuple):
    """The LDRB rule's directions per node: ``fibres`` and ``sheets`` (N, 3) unit vectors, orthogonal to each
    other, and the ventricular coordinates they come from."""

    fibres: NDArray[np.float64]
    sheets: NDArray[np.float64]
    coordinates: dict[str, NDArray[np.float64]]


def ldrb_frames(
    mesh: Mesh,
    helix_endo: float = HELIX_ENDO,
    helix_epi: float = HELIX_EPI,
    sheet_endo: float = SHEET_ENDO,
    sheet_epi: float = SHEET_EPI,
) -> Frames:
    """Fibres and sheets of a ventricular volume mesh (module docstring) and its coordinates.

    The sheet direction turns about the fibre, from the frame's in-wall direction orthogonal to the fibre
    towards the transmural one, by the sheet angle ``beta(d) = sheet_endo (1 - d) + sheet_epi d`` (Bayer et
    al.'s defaults -65 and +25 degrees). On a biventricle the frames are blended first and turned after, so
    that the fibres do not depend on the sheet angles.
    """
    solves = _solves(mesh)
    d, psi = solves.transmural, node_gradients(mesh, solves.apicobasal)
    wall = _rotated(_frames(mesh, node_gradients(mesh, d), psi), helix_endo * (1.0 - d) + helix_epi * d)
    if solves.lv is not None:
        septal = helix_endo * (1.0 - 2.0 * solves.rv_share)
        q_lv = _rotated(_frames(mesh, -node_gradients(mesh, solves.lv), psi), septal)
        q_rv = _rotated(_frames(mesh, node_gradients(mesh, solves.rv), psi), septal)
        wall = _bislerp(_bislerp(q_lv, q_rv, solves.rv_share), wall, d)
    beta = np.radians(sheet_endo * (1.0 - d) + sheet_epi * d)[:, None]
    sheets = np.cos(beta) * wall[:, :, 1] + np.sin(beta) * wall[:, :, 2]
    return Frames(_unit(wall[:, :, 0]), _unit(sheets), _coordinates(solves))


def ldrb_fibres(
    mesh: Mesh, helix_endo: float = HELIX_ENDO, helix_epi: float = HELIX_EPI
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]]]:
    """Fibres (N, 3) of a ventricular volume mesh (module docstring) and its :func:`ventricular_coordinates`."""
    frames = ldrb_frames(mesh, helix_endo, helix_epi)
    return frames.fibres, frames.coordinates


def with_rule_fibres(mesh: Mesh, helix: tuple[float, float] = (HELIX_ENDO, HELIX_EPI)) -> tuple[Mesh, dict]:
    """``mesh`` with rule-based fibres and sheets (:func:`ldrb_frames`, helix angles ``helix`` at the endocardium
    and epicardium) unless it has its own, and the ventricular coordinates of the rule."""
    rule = ldrb_frames(mesh, *helix)
    if mesh.fibres is not None:
        return mesh, rule.coordinates
    return dataclasses.replace(mesh, fibres=rule.fibres, sheets=rule.sheets), rule.coordinates
