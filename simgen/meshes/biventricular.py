"""Procedural biventricular (BiV) geometry: LV shell plus an RV wrapped on its +x side.

The domain is ``(LV_epi u RV_epi) - LV_endo - (RV_endo - LV_epi)`` below the
base plane ``z = base_z``: the RV cavity stops at the LV epicardium, so the
septum keeps the full LV wall thickness (as in the ``cardiac-geometries``
BiV ellipsoid). LV surfaces are spheroids about the z axis (tri-axial for an
eccentricity index above 1); the RV
surfaces are tri-axial ellipsoids centred at ``rv_centre`` (shifted to +x).

Meshing extends the column structure of :func:`simgen.meshes.ellipsoid.lv_ellipsoid`.
Every node ``i`` of the LV parametric triangulation defines a ray
``p(t) = endo_i + t (epi_i - endo_i)``: ``t in [0, 1]`` is the LV wall (``L``
prism layers). Where the ray continues through the RV, ``t in [1, t_endo]`` is
RV cavity (not meshed) and ``[t_endo, t_epi]`` the RV free wall (``L_rv``
layers); ``t_endo``, ``t_epi`` are the exits from the RV ellipsoids (convex,
so one root each). Where the RV wall thins out towards the interventricular
groove, its layers merge and finally collapse onto the LV epicardium; the
prisms whose vertical edges collapsed become pyramids or tetrahedra
(zero-volume pieces are dropped). RV walls thinner than 0.45 spacings are
collapsed (or thickened to that where they border the cavity), so no RV
element is flatter than that; cavities shallower than 0.15 spacings are
filled, so the two cavity surfaces never nearly touch. Where a cavity column
would still pinch the boundary (non-manifold edge or vertex), the cavity
columns around it are filled and the mesh rebuilt.

The LV deformations (:meth:`LVGeometry.column_shift`: apex offset, bumps)
translate every node of a column, RV nodes included, once the mesh is built.
Without them the surfaces lie on the analytic ones, the LV part has the quality of the LV
mesh, and the walls are resolved at any node count (one element across at
500 nodes). The rays diverge, so RV edges in the wall plane are ~1.4x longer
than LV epicardial ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.ellipsoid import LVGeometry, check_mesh_request, parametric_triangulation, stack_prisms
from simgen.meshes.topology import boundary_faces, extract_surface, signed_volumes
from simgen.meshes.validate import non_manifold_nodes, validate_mesh

__all__ = ["BiVGeometry", "biv_ellipsoid"]

_COLLAPSE = 0.45  # RV walls thinner than this many spacings collapse onto the LV epicardium
_MIN_GAP = 0.15  # RV cavities shallower than this many spacings are closed (wall filled)


@dataclass(frozen=True)
class BiVGeometry:
    """Adult-sized BiV: the LV part, the RV ellipsoids (mm) about their centre.

    LV as :class:`~simgen.meshes.ellipsoid.LVGeometry` (10 mm wall, 80 mm
    apex-to-base; its base plane is the BiV's, its deformations move the RV
    with the LV columns the RV nodes lie on). RV: endocardial semi-axes
    ``(x, y, z)`` = (36, 38, 50) around (18, 0, 0), 5 mm free wall; its
    cavity wraps about 160 degrees of the LV at the base, is up to ~19 mm
    wide and reaches down to z = -50 mm (LV endocardial apex: -57 mm).
    """

    lv: LVGeometry = field(default_factory=LVGeometry)
    rv_centre: tuple[float, float, float] = (18.0, 0.0, 0.0)
    rv_endo_axes: tuple[float, float, float] = (36.0, 38.0, 50.0)
    rv_epi_axes: tuple[float, float, float] = (41.0, 43.0, 55.0)

    def __post_init__(self) -> None:
        if not all(0 < a < b for a, b in zip(self.rv_endo_axes, self.rv_epi_axes)):
            raise MeshError("BiV geometry: RV endocardial semi-axes must be positive, below epicardial ones")
        if self.base_z >= self.rv_centre[2] + self.rv_endo_axes[2]:
            raise MeshError("BiV geometry: the base plane must cut the RV")
        if self.rv_centre[0] + self.rv_endo_axes[0] <= self.lv.radii(1)[0]:
            raise MeshError("BiV geometry: the RV cavity must reach beyond the LV epicardium on the +x side")

    @property
    def base_z(self) -> float:
        """Height of the base plane (the LV's)."""
        return self.lv.base_z

    @property
    def rv_wall(self) -> float:
        """Nominal RV free-wall thickness (mm)."""
        return float(np.mean(np.subtract(self.rv_epi_axes, self.rv_endo_axes)))

    def rv_crossing(self, origin: NDArray, direction: NDArray, epi: bool) -> tuple[NDArray, NDArray]:
        """Entry and exit ``t`` of ``origin + t direction`` through an RV ellipsoid (NaN: missed)."""
        axes = np.asarray(self.rv_epi_axes if epi else self.rv_endo_axes)
        o = (origin - np.asarray(self.rv_centre)) / axes
        d = direction / axes
        a, b, c = (d * d).sum(-1), 2 * (o * d).sum(-1), (o * o).sum(-1) - 1
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore"):
            root = np.where(disc > 0, np.sqrt(disc), np.nan)
        return (-b - root) / (2 * a), (-b + root) / (2 * a)

    def inside_rv(self, points: NDArray, epi: bool) -> NDArray[np.bool_]:
        axes = np.asarray(self.rv_epi_axes if epi else self.rv_endo_axes)
        return (((points - np.asarray(self.rv_centre)) / axes) ** 2).sum(-1) < 1


@dataclass
class _Columns:
    """Nodes of one BiV mesh and the per-vertex column bookkeeping."""

    points: NDArray[np.float64]  # undeformed (see :meth:`LVGeometry.column_shift`)
    st: NDArray[np.float64]  # (n, 2) parametric (s, theta) of each column
    tris: NDArray[np.int64]  # parametric triangles
    n: int  # parametric vertices
    layers: int  # LV prism layers; LV node l * n + i
    rv_ids: NDArray[np.int64]  # (L_rv + 1, n) RV column node ids (collapsed ones repeat)
    outer: NDArray[np.int64]  # (n,) outermost node of each column
    ring: NDArray[np.bool_]  # base-ring vertices
    cavity: NDArray[np.bool_]  # vertices whose ray crosses the RV cavity

    def lv_ids(self) -> NDArray[np.int64]:
        """(L + 1, n) LV column node ids."""
        return np.arange((self.layers + 1) * self.n).reshape(-1, self.n)

    def column_of(self) -> NDArray[np.int64]:
        """Parametric vertex (column) of every node."""
        column = np.full(len(self.points), -1)
        for level_ids in [self.lv_ids(), self.rv_ids]:
            column[level_ids] = np.arange(self.n)
        return column

    def n_surface_nodes(self) -> int:
        """Boundary node count, without building the tetrahedra."""
        on = np.zeros(len(self.points), dtype=bool)
        on[: self.n] = True
        on[self.outer] = True
        on[self.lv_ids()[:, self.ring]] = True
        on[self.rv_ids[:, self.ring]] = True
        near = np.unique(self.tris[self.cavity[self.tris].any(axis=1)])
        on[self.lv_ids()[-1, near]] = True
        on[self.rv_ids[0, near]] = True
        return int(on.sum())


def _rv_columns(
    geom: BiVGeometry, st: NDArray, tris: NDArray, spacing: float, demoted: NDArray[np.bool_]
) -> tuple[NDArray, ...]:
    """Per parametric vertex: ray origin and direction, direction length, RV wall start ``t``,
    wall thickness (mm, 0 = collapsed) and the cavity flag."""
    lv = geom.lv
    endo = lv.surface_point(st[:, 0], st[:, 1], 0.0)
    d = lv.surface_point(st[:, 0], st[:, 1], 1.0) - endo
    length = np.linalg.norm(d, axis=1)
    epi = endo + d
    (endo_in, t_endo), (epi_in, t_epi) = (geom.rv_crossing(endo, d, epi=flag) for flag in (False, True))
    in_cavity, in_rv = geom.inside_rv(epi, epi=False), geom.inside_rv(epi, epi=True)
    # The column model needs every ray to start inside an RV ellipsoid it crosses.
    for inside, t_in, t_out, what in ((in_cavity, endo_in, t_endo, "cavity"), (in_rv, epi_in, t_epi, "wall")):
        z_in = endo[:, 2] + t_in * d[:, 2]
        missed = ~inside & (t_in > 1) & (z_in < geom.base_z) & ((t_out - t_in) * length > 0.5 * spacing)
        if missed.any():
            raise MeshError(
                f"BiV geometry: rays normal to the LV wall enter the RV {what} away from the LV "
                "epicardium (RV too far from the LV, wrapped under its apex, or meeting it at an "
                "obtuse angle); move the RV centre towards the LV or shrink the RV"
            )
    cavity = in_cavity & ((t_endo - 1) * length > _MIN_GAP * spacing) & ~demoted
    start = np.where(cavity, t_endo, 1.0)
    wall = np.where(in_rv, (t_epi - start) * length, 0.0)
    # A cavity next to a collapsed column would pinch the boundary: keep a minimal wall there.
    near_cavity = np.zeros(len(st), dtype=bool)
    near_cavity[tris[cavity[tris].any(axis=1)].ravel()] = True
    floor = _COLLAPSE * spacing
    wall = np.where(near_cavity & (wall < floor), floor, wall)
    wall[wall < floor] = 0.0
    return endo, d, length, start, wall, cavity


def _columns(geom: BiVGeometry, spacing: float, layers: int, rv_layers: int, demoted: NDArray | None) -> _Columns:
    """Nodes: ``L + 1`` LV layers, then RV cavity-side nodes, then RV layers 1..L_rv."""
    lv = geom.lv
    st, tris, ring = parametric_triangulation(lv, spacing)
    n = len(st)
    demoted = np.zeros(n, dtype=bool) if demoted is None else demoted
    endo, d, length, start, wall, cavity = _rv_columns(geom, st, tris, spacing, demoted)
    lv_points = [lv.surface_point(st[:, 0], st[:, 1], l / layers) for l in range(layers + 1)]
    lv_epi = layers * n + np.arange(n)

    # Distinct RV layers per column: thin walls merge layers, zero walls collapse.
    distinct = np.clip(np.round(wall / geom.rv_wall * rv_layers), 1, rv_layers).astype(np.int64)
    distinct[wall == 0] = 0
    n_lv = (layers + 1) * n
    new_bottom = np.flatnonzero(cavity)
    rv_ids = np.empty((rv_layers + 1, n), dtype=np.int64)
    rv_ids[0] = lv_epi
    rv_ids[0, new_bottom] = n_lv + np.arange(len(new_bottom))
    extra = [endo[new_bottom] + start[new_bottom, None] * d[new_bottom]]
    next_id = n_lv + len(new_bottom)
    for level in range(1, rv_layers + 1):
        grows = distinct >= level
        ids = np.flatnonzero(grows)
        rv_ids[level] = rv_ids[level - 1]
        rv_ids[level, ids] = next_id + np.arange(len(ids))
        next_id += len(ids)
        frac = level / distinct[ids]
        t = start[ids] + frac * wall[ids] / length[ids]
        extra.append(endo[ids] + t[:, None] * d[ids])
    points = np.concatenate(lv_points + extra)
    return _Columns(points, st, tris, n, layers, rv_ids, rv_ids[-1], ring, cavity)


def _tets(cols: _Columns) -> NDArray[np.int64]:
    """Positively oriented tetrahedra of the LV and RV prism stacks."""
    lv_tets = stack_prisms(cols.tris, cols.n, cols.layers)
    rv_tets = cols.rv_ids.ravel()[stack_prisms(cols.tris, cols.n, cols.rv_ids.shape[0] - 1)]
    s = np.sort(rv_tets, axis=1)
    rv_tets = rv_tets[(s[:, 1:] != s[:, :-1]).all(axis=1)]  # drop pieces of collapsed prisms
    tets = np.concatenate([lv_tets, rv_tets])
    negative = signed_volumes(cols.points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return tets


def _build(geom: BiVGeometry, spacing: float, layers: int, rv_layers: int) -> tuple[_Columns, NDArray]:
    """Columns and tetrahedra; cavity columns near non-manifold spots are filled until none is left."""
    demoted = None
    for _ in range(20):
        cols = _columns(geom, spacing, layers, rv_layers, demoted)
        tets = _tets(cols)
        bad = non_manifold_nodes(tets)
        if len(bad) == 0:
            return cols, tets
        bad_vertices = np.zeros(cols.n, dtype=bool)
        bad_vertices[cols.column_of()[bad]] = True
        demoted = np.zeros(cols.n, dtype=bool) if demoted is None else demoted
        demoted[cols.tris[bad_vertices[cols.tris].any(axis=1)].ravel()] = True
    raise MeshError("BiV mesh: could not remove non-manifold configurations; check the geometry")


def _node_sets(geom: BiVGeometry, cols: _Columns, tets: NDArray) -> dict[str, NDArray]:
    """Boundary faces labelled base / LV endo / epicardium (outermost column nodes) / RV endo."""
    faces = boundary_faces(tets)
    n_pts = len(cols.points)

    def all_in(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        return mask[faces].all(axis=1)

    on_base = np.abs(cols.points[:, 2] - geom.base_z) < 1e-9 * max(1.0, abs(geom.base_z))
    base = all_in(on_base)
    lv_endo = ~base & all_in(np.arange(n_pts) < cols.n)
    outer = np.zeros(n_pts, dtype=bool)
    outer[cols.outer] = True
    epi = ~base & ~lv_endo & all_in(outer)
    rv_endo = ~(base | lv_endo | epi)
    sets = {
        "base": faces[base],
        "lv_endocardium": faces[lv_endo],
        "rv_endocardium": faces[rv_endo],
        "epicardium": faces[epi],
        "endocardium": faces[lv_endo | rv_endo],
        "surface": faces,
    }
    return {key: np.unique(f) for key, f in sets.items()}


def _layer_counts(geom: BiVGeometry, spacing: float) -> tuple[int, int]:
    """LV and RV layer counts giving near-isotropic elements."""
    return max(1, round(geom.lv.thickness() / spacing)), max(1, round(geom.rv_wall / spacing))


def biv_ellipsoid(
    n_nodes: int = 2000,
    kind: Literal["tetra", "triangle"] = "tetra",
    geometry: BiVGeometry | None = None,
    name: str = "biv",
) -> Mesh:
    """Biventricular mesh with about ``n_nodes`` nodes (within a few percent).

    Parameters
    ----------
    n_nodes : target node count of the returned mesh (500 - 50,000).
    kind : ``"tetra"`` for the volume mesh, ``"triangle"`` for its closed boundary surface.
    geometry : LV part, RV ellipsoids; defaults to :class:`BiVGeometry`
        (:meth:`simgen.meshes.shapes.BiVShape.geometry` gives one from clinical parameters).

    Node sets: ``surface``, ``epicardium``, ``endocardium`` (= ``lv_endocardium`` u
    ``rv_endocardium``; the RV septal surface counts as RV endocardium), ``base``.
    The axis runs from the LV epicardial apex to the base centre; its reference
    direction (+x) points to the RV.
    """
    check_mesh_request(kind, n_nodes, smallest=300)
    geom = geometry or BiVGeometry()

    def count(spacing: float, layers: int, rv_layers: int) -> int:
        cols = _columns(geom, spacing, layers, rv_layers, None)
        return len(cols.points) if kind == "tetra" else cols.n_surface_nodes()

    # Node counts scale like spacing^-2 at fixed layer counts: fix the layers from an
    # isotropic estimate, then rescale the spacing until the count is on target.
    spacing = (geom.lv.thickness() * 3e4 / n_nodes) ** 0.5
    for fixed in (False, True):
        for _ in range(10):
            if not fixed:
                layers, rv_layers = _layer_counts(geom, spacing)
            got = count(spacing, layers, rv_layers)
            if abs(got / n_nodes - 1) < (0.005 if fixed else 0.1):
                break
            spacing *= (got / n_nodes) ** (0.5 if fixed else 1 / 3)

    cols, tets = _build(geom, spacing, layers, rv_layers)
    node_sets = _node_sets(geom, cols, tets)
    points = cols.points + geom.lv.column_shift(cols.st[:, 0], cols.st[:, 1])[cols.column_of()]
    mesh = Mesh(points=points, cells=tets, node_sets=node_sets, axis=geom.lv.long_axis(), name=name)
    return validate_mesh(mesh if kind == "tetra" else extract_surface(mesh))
