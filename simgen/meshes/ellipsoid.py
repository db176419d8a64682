"""Procedural left ventricle: a truncated prolate-spheroid shell.

The shell lies between an endocardial and an epicardial half-spheroid (long
axis = z, apex at negative z, base plane at ``z = base_z``). One parametric
triangulation (longitude x height) is shared by every transmural layer, so the
volume mesh is a stack of prisms, each split into three tetrahedra with the
vertex-ordering rule that makes neighbouring prisms conform.

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
from simgen.meshes.topology import extract_surface, signed_volumes

__all__ = ["LVGeometry", "lv_ellipsoid", "parametric_triangulation", "stack_prisms", "check_mesh_request"]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True)
class LVGeometry:
    """Semi-axes (mm) of the endo- and epicardial spheroids and the base plane height.

    Defaults are an adult-sized LV: 80 mm apex-to-base on the epicardium, 10 mm
    wall at the equator, 8 mm at the apex.
    """

    endo_short: float = 25.0
    endo_long: float = 57.0
    epi_short: float = 35.0
    epi_long: float = 65.0
    base_z: float = 15.0

    def __post_init__(self) -> None:
        if not (0 < self.endo_short < self.epi_short and 0 < self.endo_long < self.epi_long):
            raise MeshError("LV geometry: endocardial semi-axes must be smaller than epicardial ones")
        if not -self.endo_long < self.base_z < self.endo_long:
            raise MeshError("LV geometry: base plane must cut both spheroids")

    def surface_point(self, s: NDArray, theta: NDArray, t: float) -> NDArray[np.float64]:
        """Points at height parameter ``s`` (0 apex, 1 base), angle ``theta`` and wall depth ``t``.

        ``t = 0`` is the endocardium and ``t = 1`` the epicardium; intermediate
        layers interpolate linearly between the two surfaces.
        """
        endo = self._spheroid(s, theta, self.endo_short, self.endo_long)
        epi = self._spheroid(s, theta, self.epi_short, self.epi_long)
        return (1.0 - t) * endo + t * epi

    def _spheroid(self, s: NDArray, theta: NDArray, r_short: float, r_long: float) -> NDArray:
        nu_base = np.arccos(self.base_z / r_long)
        nu = np.pi - np.asarray(s) * (np.pi - nu_base)
        return np.stack(
            [r_short * np.sin(nu) * np.cos(theta), r_short * np.sin(nu) * np.sin(theta), r_long * np.cos(nu)],
            axis=-1,
        )

    def mid_area_density(self, s: NDArray) -> NDArray:
        """Area of the mid-wall surface per unit ``s`` (integrated over theta)."""
        ds = 1e-4
        p0 = self.surface_point(s, np.zeros_like(s), 0.5)
        p1 = self.surface_point(s + ds, np.zeros_like(s), 0.5)
        radius = np.hypot(p0[..., 0], p0[..., 1])
        return 2 * np.pi * radius * np.linalg.norm(p1 - p0, axis=-1) / ds

    def mid_base_circumference(self) -> float:
        return 2 * np.pi * float(np.hypot(*self.surface_point(np.array(1.0), np.array(0.0), 0.5)[:2]))

    def thickness(self) -> float:
        """Mean wall thickness (mm) between equator and apex."""
        return 0.5 * ((self.epi_short - self.endo_short) + (self.epi_long - self.endo_long))

    def long_axis(self) -> LongAxis:
        """Frame from the epicardial apex to the base centre, angle 0 along +x."""
        return LongAxis(
            apex=np.array([0.0, 0.0, -self.epi_long]),
            base=np.array([0.0, 0.0, self.base_z]),
            reference=np.array([1.0, 0.0, 0.0]),
        )


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
    area = cdf[-1]
    cell_area = np.sqrt(3.0) / 2.0 * spacing**2
    # Interior points stop half a spacing short of the base ring to avoid slivers.
    length_per_s = np.linalg.norm(
        geom.surface_point(np.array(1.0), np.array(0.0), 0.5)
        - geom.surface_point(np.array(0.99), np.array(0.0), 0.5)
    ) / 0.01
    s_gap = 0.5 * spacing / length_per_s
    area_inner = np.interp(1.0 - s_gap, grid, cdf)
    n_inner = max(int(round(area_inner / cell_area)), 8)
    n_ring = max(int(round(geom.mid_base_circumference() / spacing)), 6)
    u = (np.arange(n_inner) + 0.5) / n_inner * area_inner
    s_inner = np.interp(u, cdf, grid)
    theta_inner = np.arange(n_inner) * _GOLDEN_ANGLE
    s = np.concatenate([s_inner, np.ones(n_ring)])
    theta = np.concatenate([theta_inner, 2 * np.pi * np.arange(n_ring) / n_ring])
    # Embed on a unit sphere (apex = south pole, base ring at a fixed latitude) plus a
    # north pole, take the hull and drop the triangles that touch the pole.
    mid_long = 0.5 * (geom.endo_long + geom.epi_long)
    psi_cut = np.arccos(geom.base_z / mid_long)
    psi = np.pi - s * (np.pi - psi_cut)
    sphere = np.stack([np.sin(psi) * np.cos(theta), np.sin(psi) * np.sin(theta), np.cos(psi)], axis=1)
    sphere = np.vstack([sphere, [0.0, 0.0, 1.0]])
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
    geometry : semi-axes and base height; defaults to :class:`LVGeometry`.

    Node sets: ``surface``, ``epicardium``, ``endocardium``, ``base``.
    """
    check_mesh_request(kind, n_nodes, smallest=200)
    geom = geometry or LVGeometry()
    # Pick the transmural layer count from an isotropic estimate, then refit the
    # in-plane spacing for that integer count so the node count stays on target.
    layers = max(1, int(round(geom.thickness() / _spacing_for(geom, n_nodes, kind, None))))
    spacing = _spacing_for(geom, n_nodes, kind, layers)

    st, tris, ring = parametric_triangulation(geom, spacing)
    n = len(st)
    points = np.concatenate(
        [geom.surface_point(st[:, 0], st[:, 1], layer / layers) for layer in range(layers + 1)]
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
    return mesh if kind == "tetra" else extract_surface(mesh)
