"""Procedural left ventricle: a truncated prolate-spheroid shell.

The shell lies between an endocardial and an epicardial half-spheroid (long
axis = z, apex at negative z, base plane at ``z = base_z``). One parametric
triangulation (longitude x height) is shared by every transmural layer, so the
volume mesh is a stack of prisms, each split into three tetrahedra with the
vertex-ordering rule that makes neighbouring prisms conform. Optional
deformations (an elliptic short axis, an apex offset, smooth random bumps;
see :class:`LVGeometry`) make the shell less regular without changing the
construction.

The parametric triangulation is the convex hull of near-equal-area points on a
unit sphere (a spherical Delaunay triangulation), which has no pole
singularity and accepts any node count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull

from shared.errors import MeshError
from shared.mesh import LongAxis, Mesh
from simgen.meshes.harmonics import degree_of, harmonic_field
from simgen.meshes.topology import extract_surface, signed_volumes
from simgen.meshes.validate import validate_mesh

__all__ = ["LVGeometry", "lv_ellipsoid", "parametric_triangulation", "stack_prisms", "check_mesh_request"]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True)
class LVGeometry:
    """Semi-axes (mm) of the endo- and epicardial spheroids, the base plane height and deformations.

    Defaults are an adult-sized LV: 80 mm apex-to-base on the epicardium, 10 mm
    wall at the equator, 8 mm at the apex. ``endo_short`` and ``epi_short``
    are the semi-axes along y; along x (towards the septum / RV) the
    endocardial one is ``endo_short / eccentricity_index`` and the wall keeps
    its thickness ``epi_short - endo_short``.

    Two deformations translate whole transmural columns horizontally, so wall
    thickness along a column, heights and the flat base are unchanged:
    ``apex_offset`` (x, y in mm) shifts the apex sideways, fading with
    height to zero at the base; ``bumps`` are the coefficients (mm) of a
    field ``f`` of real spherical harmonics of degree 2 and up
    (:mod:`simgen.meshes.harmonics`) on the parametric unit sphere, and the
    column at sphere point ``u`` moves by ``f(u)`` times ``(u_x, u_y, 0)``:
    away from the long axis where ``f > 0``, fading to zero at the apex.
    """

    endo_short: float = 25.0
    endo_long: float = 57.0
    epi_short: float = 35.0
    epi_long: float = 65.0
    base_z: float = 15.0
    eccentricity_index: float = 1.0
    apex_offset: tuple[float, float] = (0.0, 0.0)
    bumps: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (0 < self.endo_short < self.epi_short and 0 < self.endo_long < self.epi_long):
            raise MeshError("LV geometry: endocardial semi-axes must be smaller than epicardial ones")
        if not -self.endo_long < self.base_z < self.endo_long:
            raise MeshError("LV geometry: base plane must cut both spheroids")
        if not (np.isfinite(self.eccentricity_index) and self.eccentricity_index > 0):
            raise MeshError(f"LV geometry: eccentricity_index must be positive, got {self.eccentricity_index}")
        object.__setattr__(self, "apex_offset", tuple(float(v) for v in self.apex_offset))
        object.__setattr__(self, "bumps", tuple(float(v) for v in self.bumps))
        if len(self.apex_offset) != 2:
            raise MeshError(f"LV geometry: apex_offset must be (x, y), got {self.apex_offset}")
        if self.bumps:
            degree_of(len(self.bumps))

    def radii(self, t: float) -> tuple[float, float, float]:
        """Semi-axes (x, y, z) of the endocardium (``t = 0``) or the epicardium (``t = 1``)."""
        narrowing = self.endo_short * (1.0 - 1.0 / self.eccentricity_index)  # 0 for a circular section
        if t == 0:
            return self.endo_short - narrowing, self.endo_short, self.endo_long
        return self.epi_short - narrowing, self.epi_short, self.epi_long

    def surface_point(self, s: NDArray, theta: NDArray, t: float) -> NDArray[np.float64]:
        """Undeformed points at height parameter ``s`` (0 apex, 1 base), angle ``theta`` and wall depth ``t``.

        ``t = 0`` is the endocardium and ``t = 1`` the epicardium; intermediate
        layers interpolate linearly between the two surfaces. Add
        :meth:`column_shift` for the deformed shape.
        """
        endo = self._spheroid(s, theta, *self.radii(0))
        epi = self._spheroid(s, theta, *self.radii(1))
        return (1.0 - t) * endo + t * epi

    def _spheroid(self, s: NDArray, theta: NDArray, r_x: float, r_y: float, r_long: float) -> NDArray:
        nu_base = np.arccos(self.base_z / r_long)
        nu = np.pi - np.asarray(s) * (np.pi - nu_base)
        return np.stack(
            [r_x * np.sin(nu) * np.cos(theta), r_y * np.sin(nu) * np.sin(theta), r_long * np.cos(nu)],
            axis=-1,
        )

    def sphere_point(self, s: NDArray, theta: NDArray) -> NDArray[np.float64]:
        """Parametric unit sphere: apex = south pole, base ring at the mid-wall base latitude."""
        psi = np.pi - np.asarray(s) * (np.pi - np.arccos(self._cos_cut))
        return np.stack([np.sin(psi) * np.cos(theta), np.sin(psi) * np.sin(theta), np.cos(psi)], axis=-1)

    @property
    def _cos_cut(self) -> float:
        """Height of the base ring on the parametric sphere (the mid-wall base plane)."""
        return self.base_z / (0.5 * (self.endo_long + self.epi_long))

    def column_shift(self, s: NDArray, theta: NDArray) -> NDArray[np.float64]:
        """Horizontal translation (mm) of the transmural column at ``(s, theta)``: bumps plus apex offset."""
        unit = self.sphere_point(s, theta)
        weight = (self._cos_cut - unit[..., 2]) / (self._cos_cut + 1.0)  # 1 at the apex, 0 at the base
        radial = unit * np.array([1.0, 1.0, 0.0])  # (sin psi cos theta, sin psi sin theta, 0)
        offset = np.array([*self.apex_offset, 0.0])
        return harmonic_field(self.bumps, unit)[..., None] * radial + weight[..., None] * offset

    def mid_area_density(self, s: NDArray) -> NDArray:
        """Area of the undeformed mid-wall surface per unit ``s`` (integrated over theta)."""
        ds = 1e-4
        zero, right = np.zeros_like(s), np.full_like(s, np.pi / 2)
        p0, q0 = self.surface_point(s, zero, 0.5), self.surface_point(s, right, 0.5)
        p1, q1 = self.surface_point(s + ds, zero, 0.5), self.surface_point(s + ds, right, 0.5)
        slope = 0.5 * (np.linalg.norm(p1 - p0, axis=-1) + np.linalg.norm(q1 - q0, axis=-1))
        return _ellipse_perimeter(np.hypot(p0[..., 0], p0[..., 1]), q0[..., 1]) * slope / ds

    def mid_base_circumference(self) -> float:
        """Perimeter of the undeformed mid-wall base ring."""
        p = self.surface_point(np.array(1.0), np.array(0.0), 0.5)
        q = self.surface_point(np.array(1.0), np.array(np.pi / 2), 0.5)
        return float(_ellipse_perimeter(np.hypot(p[0], p[1]), q[1]))

    def thickness(self) -> float:
        """Mean wall thickness (mm) between equator and apex."""
        return 0.5 * ((self.epi_short - self.endo_short) + (self.epi_long - self.endo_long))

    def long_axis(self) -> LongAxis:
        """Frame from the (shifted) epicardial apex to the base centre, angle 0 along +x."""
        apex = np.array([self.apex_offset[0], self.apex_offset[1], -self.epi_long])
        base = np.array([0.0, 0.0, self.base_z])
        d = (base - apex) / np.linalg.norm(base - apex)
        reference = np.array([1.0, 0.0, 0.0]) - d[0] * d
        return LongAxis(apex=apex, base=base, reference=reference / np.linalg.norm(reference))


def _ellipse_perimeter(a: NDArray, b: NDArray) -> NDArray:
    """Ramanujan's perimeter of an ellipse with semi-axes ``a``, ``b`` (exactly ``2 pi a`` for a circle)."""
    h = ((a - b) / (a + b)) ** 2
    return np.pi * (a + b) * (1.0 + 3.0 * h / (10.0 + np.sqrt(4.0 - 3.0 * h)))


def parametric_triangulation(geom: LVGeometry, spacing: float) -> tuple[NDArray, NDArray, NDArray]:
    """Near-equal-area ``(s, theta)`` samples of the mid-wall surface and their triangles.

    Parameters
    ----------
    geom : the LV whose mid-wall area density spaces the samples.
    spacing : target in-plane edge length (mm); each triangle covers about
        ``sqrt(3) / 2 spacing^2`` of mid-wall area.

    Returns
    -------
    st : (n, 2) float64 ``(s, theta)`` per vertex, ``s`` in [0, 1] from apex to base.
    tris : (T, 3) int64 triangles, oriented outward on the embedding sphere.
    ring : (n,) bool, True for the vertices on the base ring ``s = 1``.
    """
    grid = np.linspace(0.0, 1.0, 2001)
    density = geom.mid_area_density(grid)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(grid))])
    cell_area = np.sqrt(3.0) / 2.0 * spacing**2
    # Interior points stop half a spacing short of the base ring to avoid slivers.
    length_per_s = (
        np.linalg.norm(
            geom.surface_point(np.array(1.0), np.array(0.0), 0.5)
            - geom.surface_point(np.array(0.99), np.array(0.0), 0.5)
        )
        / 0.01
    )
    s_gap = 0.5 * spacing / length_per_s
    area_inner = np.interp(1.0 - s_gap, grid, cdf)
    n_inner = max(int(round(area_inner / cell_area)), 8)
    n_ring = max(int(round(geom.mid_base_circumference() / spacing)), 6)
    u = (np.arange(n_inner) + 0.5) / n_inner * area_inner
    s_inner = np.interp(u, cdf, grid)
    theta_inner = np.arange(n_inner) * _GOLDEN_ANGLE
    s = np.concatenate([s_inner, np.ones(n_ring)])
    theta = np.concatenate([theta_inner, 2 * np.pi * np.arange(n_ring) / n_ring])
    # Embed on the parametric unit sphere plus its north pole, take the hull and drop the
    # triangles that touch the pole.
    sphere = np.vstack([geom.sphere_point(s, theta), [0.0, 0.0, 1.0]])
    hull = ConvexHull(sphere)
    tris = hull.simplices[(hull.simplices < len(s)).all(axis=1)]
    # Orient every triangle outward on the sphere.
    p = sphere[tris]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", normal, p.mean(axis=1)) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    ring = np.zeros(len(s), dtype=bool)
    ring[n_inner:] = True
    return np.stack([s, theta], axis=1), tris.astype(np.int64), ring


def stack_prisms(tris: NDArray[np.integer], n_per_layer: int, n_layers: int) -> NDArray[np.int64]:
    """Tetrahedra filling ``n_layers`` prism layers over one triangulation.

    Node ``l * n_per_layer + i`` is parametric node ``i`` in layer ``l``. Each
    prism is split along the diagonals that start at the lower-indexed bottom
    vertex, which is consistent across shared quad faces.
    """
    a, b, c = np.sort(tris, axis=1).T
    tets = []
    for layer in range(n_layers):
        lo, hi = layer * n_per_layer, (layer + 1) * n_per_layer
        tets += [
            np.stack([a + lo, b + lo, c + lo, c + hi], axis=1),
            np.stack([a + lo, b + lo, b + hi, c + hi], axis=1),
            np.stack([a + lo, a + hi, b + hi, c + hi], axis=1),
        ]
    return np.concatenate(tets)


def check_mesh_request(kind: str, n_nodes: int, smallest: int, largest: int = 200_000) -> None:
    """Raise :class:`MeshError` unless ``kind`` is a mesh kind and ``smallest <= n_nodes <= largest``."""
    if kind not in ("tetra", "triangle"):
        raise MeshError(f"unknown mesh kind {kind!r} (use 'tetra' or 'triangle')")
    if not smallest <= n_nodes <= largest:
        raise MeshError(f"n_nodes={n_nodes} outside the supported range {smallest}..{largest}")


def _node_count(geom: LVGeometry, spacing: float, layers: float, kind: str) -> float:
    """Approximate node count for an in-plane spacing and a number of element layers."""
    grid = np.linspace(0.0, 1.0, 2001)
    density = geom.mid_area_density(grid)
    area = float(np.sum(0.5 * (density[1:] + density[:-1]) * np.diff(grid)))
    n_param = area / (np.sqrt(3.0) / 2.0 * spacing**2)
    n_ring = geom.mid_base_circumference() / spacing
    if kind == "tetra":
        return (layers + 1) * n_param
    return 2 * n_param + (layers - 1) * n_ring


def _spacing_for(geom: LVGeometry, n_nodes: int, kind: str, layers: int | None) -> float:
    """In-plane spacing giving ``n_nodes`` (layers follow the spacing when ``None``)."""
    lo, hi = 0.05, 100.0  # mm; the node count decreases with the spacing
    for _ in range(60):
        mid = np.sqrt(lo * hi)
        n_layers = max(1.0, geom.thickness() / mid) if layers is None else layers
        lo, hi = (mid, hi) if _node_count(geom, mid, n_layers, kind) > n_nodes else (lo, mid)
    return float(np.sqrt(lo * hi))


def lv_ellipsoid(
    n_nodes: int = 2000,
    kind: Literal["tetra", "triangle"] = "tetra",
    geometry: LVGeometry | None = None,
    name: str = "lv",
) -> Mesh:
    """Truncated prolate-spheroid LV mesh with about ``n_nodes`` nodes.

    Parameters
    ----------
    n_nodes : target node count (500 - 50,000); the result is within a few percent.
    kind : ``"tetra"`` for the volume mesh, ``"triangle"`` for its closed boundary
        surface (endocardium, epicardium and the base rim).
    geometry : semi-axes, base height and deformations; defaults to :class:`LVGeometry`
        (:meth:`simgen.meshes.shapes.LVShape.geometry` gives one from clinical parameters).

    Node sets: ``surface``, ``epicardium``, ``endocardium``, ``base``. The mesh is
    validated (:func:`~simgen.meshes.validate.validate_mesh`).
    """
    check_mesh_request(kind, n_nodes, smallest=200)
    geom = geometry or LVGeometry()
    # Pick the transmural layer count from an isotropic estimate, then refit the
    # in-plane spacing for that integer count so the node count stays on target.
    layers = max(1, int(round(geom.thickness() / _spacing_for(geom, n_nodes, kind, None))))
    spacing = _spacing_for(geom, n_nodes, kind, layers)

    st, tris, ring = parametric_triangulation(geom, spacing)
    n = len(st)
    shift = geom.column_shift(st[:, 0], st[:, 1])
    points = np.concatenate(
        [geom.surface_point(st[:, 0], st[:, 1], layer / layers) + shift for layer in range(layers + 1)]
    )
    tets = stack_prisms(tris, n, layers)
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]

    ids = np.arange(n)
    node_sets = {
        "endocardium": ids,
        "epicardium": ids + layers * n,
        "base": np.concatenate([ids[ring] + layer * n for layer in range(layers + 1)]),
    }
    node_sets["surface"] = np.unique(np.concatenate(list(node_sets.values())))
    mesh = Mesh(points=points, cells=tets, node_sets=node_sets, axis=geom.long_axis(), name=name)
    return validate_mesh(mesh if kind == "tetra" else extract_surface(mesh))
