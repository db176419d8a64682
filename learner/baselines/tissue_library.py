"""A library of plausible excitability maps on one mesh: random geodesic scars (VAE-BO's training set).

A scar is a geodesic disc on the mesh graph (edge-length weighted shortest
paths): nodes within ``radius`` mm of a centre node form the core (a = 0.5),
those within a further ``border_width`` mm the border zone (a = 0.3), the rest
is healthy (a = 0.15), the materials of the data. Centres are uniform over the
nodes and radii uniform over a fraction of the mesh's geodesic diameter, so
the library scales with the heart rather than with its resolution. Built from
the mesh alone: no simulator is involved.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from shared.errors import InputError
from shared.graph import edge_length_graph
from shared.mesh import Mesh

__all__ = ["A_CORE", "A_BORDER", "geodesic_diameter", "geodesic_scar", "scar_library"]

#: Excitability of the scar core and of its border zone (the data's materials).
A_CORE, A_BORDER = 0.5, 0.3
_A_HEALTHY = 0.15


def _graph(mesh: Mesh) -> csr_matrix:
    """Edge-length weighted adjacency of the mesh."""
    return edge_length_graph(mesh.points, mesh.edges())


def geodesic_diameter(mesh: Mesh) -> float:
    """Graph-geodesic diameter of a mesh, by a double sweep from node 0 (mm; a close lower bound)."""
    adj = _graph(mesh)
    d0 = dijkstra(adj, directed=True, indices=0)
    if not np.isfinite(d0).all():
        raise InputError(f"mesh {mesh.name!r} is not connected; a tissue library needs a connected mesh")
    far = int(np.argmax(d0))
    return float(dijkstra(adj, directed=True, indices=far).max())


def _scar_map(adj: csr_matrix, centre: int, radius: float, border_width: float) -> NDArray[np.float64]:
    dist = dijkstra(adj, directed=True, indices=centre, limit=radius + border_width)
    a = np.full(adj.shape[0], _A_HEALTHY)
    a[dist <= radius + border_width] = A_BORDER
    a[dist <= radius] = A_CORE
    return a


def geodesic_scar(mesh: Mesh, centre: int, radius: float, border_width: float = 0.0) -> NDArray[np.float64]:
    """Excitability map (N,) of one scar: core within ``radius`` mm of node ``centre``, then a border band."""
    if not 0 <= int(centre) < mesh.n_nodes:
        raise InputError(f"scar centre {centre} is not a node of the {mesh.n_nodes}-node mesh")
    if not (np.isfinite(radius) and radius >= 0 and np.isfinite(border_width) and border_width >= 0):
        raise InputError(f"radius and border_width must be finite and >= 0 mm, got {radius}, {border_width}")
    return _scar_map(_graph(mesh), int(centre), float(radius), float(border_width))


def scar_library(
    mesh: Mesh,
    count: int = 300,
    radius: tuple[float, float] = (0.08, 0.25),
    border_width: float | None = None,
    seed: int = 0,
) -> NDArray[np.float32]:
    """``count`` excitability maps (count, N): the healthy map, then ``count - 1`` random geodesic scars.

    Parameters
    ----------
    mesh : a connected mesh.
    count : number of maps (>= 2).
    radius : core radius range as fractions of the mesh's geodesic diameter.
    border_width : border-zone width in mm; ``None`` means one mean edge length
        (the data's 5 mm on the default 2,000-node LV, and still a band of
        nodes on coarse meshes).
    seed : seed of the centres and radii.
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 2:
        raise InputError(f"a tissue library needs count >= 2 maps, got {count!r}")
    lo, hi = (float(r) for r in radius)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi <= 1):
        raise InputError(f"radius must be a (low, high) pair of diameter fractions in (0, 1], got {radius!r}")
    width = mesh.mean_edge_length() if border_width is None else float(border_width)
    if not (np.isfinite(width) and width >= 0):
        raise InputError(f"border_width must be finite and >= 0 mm, got {border_width!r}")
    diameter = geodesic_diameter(mesh)
    adj = _graph(mesh)
    rng = np.random.default_rng(seed)
    centres = rng.integers(0, mesh.n_nodes, size=count - 1)
    radii = rng.uniform(lo, hi, size=count - 1) * diameter
    maps = np.empty((count, mesh.n_nodes), dtype=np.float32)
    maps[0] = _A_HEALTHY
    for i, (c, r) in enumerate(zip(centres, radii), start=1):
        maps[i] = _scar_map(adj, int(c), float(r), width)
    return maps
