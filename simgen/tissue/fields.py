"""Per-node tissue fields (excitability ``a``, diffusivity scale ``D``, label) from a spec.

Each scar has a *core* (its region: AHA segments or a Euclidean ball) and a
*border zone*: the non-core nodes within ``border_width`` mm of the core,
measured as the shortest path along mesh edges (a geodesic distance, so a
border does not jump across the LV cavity or between walls). Where the
distance starts is :data:`SCAR_BORDERS`' choice:

- ``"boundary"`` (the default): the core's boundary, which a nodal field
  places halfway along each edge that leaves the core. A node next to the
  core is half an edge from it, so a border of 5 mm is one ring of nodes on
  a mesh of 7 mm edges and two rings at 2.5 mm: the band is about as wide
  at every resolution.
- ``"nodes"``: the core's nodes. A border narrower than an edge then holds
  no node at all on a coarse mesh (the 5 mm border of the default scars
  vanishes at 1,000 nodes); stores built before ``"boundary"`` existed used
  it, and record no ``scar_border`` in their ``simulation`` attribute.

Overlaps: a core beats any border; among cores, and among borders, the
material with the higher ``a`` wins (ties: the lower ``D``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra

from shared.errors import TissueError
from shared.mesh import Mesh
from shared.tissue import (
    LABEL_BORDER,
    LABEL_CORE,
    LABEL_HEALTHY,
    Material,
    ScarSpec,
    TissueFields,
    TissueSpec,
)
from simgen.meshes.topology import edge_graph
from simgen.tissue.aha import aha_segments

__all__ = ["SCAR_BORDERS", "tissue_fields", "scar_regions"]

#: Where a border zone's width is measured from; the first is the default (module docstring).
SCAR_BORDERS = ("boundary", "nodes")


def _core(mesh: Mesh, scar: ScarSpec, index: int, segments: NDArray[np.int8] | None) -> NDArray[np.bool_]:
    if scar.region == "segments":
        assert segments is not None
        core = np.isin(segments, np.asarray(scar.segments, dtype=np.int8))
        what = f"AHA segments {list(scar.segments)}"
    else:
        if scar.node is not None:
            if not 0 <= scar.node < mesh.n_nodes:
                raise TissueError(f"scar {index}: sphere node {scar.node} out of range [0, {mesh.n_nodes})")
            centre = mesh.points[scar.node]
        else:
            centre = np.asarray(scar.centre, dtype=np.float64)
        core = np.linalg.norm(mesh.points - centre, axis=1) <= scar.radius
        what = f"sphere of radius {scar.radius} mm around {np.round(centre, 3).tolist()}"
    if not core.any():
        raise TissueError(f"scar {index}: region ({what}) selects no node of mesh {mesh.name!r}")
    return core


def scar_regions(
    mesh: Mesh, spec: TissueSpec, graph: sp.csr_matrix | None = None, border: str = SCAR_BORDERS[0]
) -> list[tuple[NDArray[np.bool_], NDArray[np.bool_]]]:
    """``(core, border)`` boolean node masks of every scar, before overlap rules.

    ``graph``: the mesh's :func:`~simgen.meshes.topology.edge_graph`, when the
    caller has it. ``border``: where the border width is measured from
    (:data:`SCAR_BORDERS`). Raises :class:`TissueError` naming the scar for an
    empty region or an out-of-range sphere node.
    """
    if border not in SCAR_BORDERS:
        raise TissueError(f"unknown scar border measure {border!r}; use one of {list(SCAR_BORDERS)}")
    segments = None
    if any(s.region == "segments" for s in spec.scars):
        segments = aha_segments(mesh)
    if graph is None and any(s.border_width > 0 for s in spec.scars):
        graph = edge_graph(mesh)
    regions = []
    for i, scar in enumerate(spec.scars):
        core = _core(mesh, scar, i, segments)
        band = np.zeros_like(core)
        if scar.border_width > 0:
            distance = _from_boundary if border == "boundary" else _from_nodes
            band = (distance(graph, core, scar.border_width) <= scar.border_width) & ~core
        regions.append((core, band))
    return regions


def _from_nodes(graph: sp.csr_matrix, core: NDArray[np.bool_], limit: float) -> NDArray[np.float64]:
    """Edge-path distance (mm) of every node from the nearest core node (inf beyond ``limit``)."""
    return dijkstra(graph, directed=False, indices=np.flatnonzero(core), limit=limit, min_only=True)


def _from_boundary(graph: sp.csr_matrix, core: NDArray[np.bool_], limit: float) -> NDArray[np.float64]:
    """Edge-path distance (mm) of every node from the core's boundary, halfway along the edges that leave
    the core (inf beyond ``limit``): a shortest-path search from one extra node joined to each node next
    to the core by half of its shortest edge into the core."""
    n = graph.shape[0]
    edges = graph.tocoo()
    leaving = core[edges.row] & ~core[edges.col]
    start = np.full(n, np.inf)
    np.minimum.at(start, edges.col[leaving], 0.5 * edges.data[leaving])
    rim = np.flatnonzero(np.isfinite(start))
    link = sp.csr_matrix((start[rim], (np.zeros(len(rim), np.int64), rim)), shape=(1, n))
    joined = sp.bmat([[graph, link.T], [link, None]], format="csr")
    return dijkstra(joined, directed=False, indices=n, limit=limit)[:n]


def tissue_fields(
    mesh: Mesh,
    spec: TissueSpec,
    max_scar_fraction: float = 0.5,
    graph: sp.csr_matrix | None = None,
    border: str = SCAR_BORDERS[0],
) -> TissueFields:
    """Per-node tissue fields of ``spec`` on ``mesh``.

    Parameters
    ----------
    mesh : the mesh (AHA segments use ``mesh.axis`` or a PCA estimate).
    spec : healthy material plus scars.
    max_scar_fraction : refuse settings whose scars (cores and borders, alone
        or together) cover more than this fraction of the nodes.
    graph : the mesh's :func:`~simgen.meshes.topology.edge_graph` (border zones),
        computed here if not given.
    border : where border widths are measured from (:data:`SCAR_BORDERS`).

    Returns
    -------
    TissueFields with float64 ``a`` and ``D`` and int8 ``label``
    (0 healthy, 1 border zone, 2 core).

    Raises
    ------
    TissueError
        Naming the scar: a region that selects no node, a sphere node out of
        range, or a whole-heart scar (more than ``max_scar_fraction``); naming
        the setting: ``D = 0`` at every node (nothing conducts).
    """
    if not 0.0 < max_scar_fraction <= 1.0:
        raise TissueError(f"max_scar_fraction={max_scar_fraction} must lie in (0, 1]")
    n = mesh.n_nodes
    a = np.full(n, spec.healthy.a, dtype=np.float64)
    D = np.full(n, spec.healthy.D, dtype=np.float64)
    label = np.full(n, LABEL_HEALTHY, dtype=np.int8)
    regions = scar_regions(mesh, spec, graph, border)

    limit = max_scar_fraction * n
    for i, (core, border) in enumerate(regions):
        covered = int(core.sum() + border.sum())
        if covered > limit:
            raise TissueError(
                f"scar {i}: whole-heart scar, core and border cover {covered / n:.1%} of the nodes "
                f"(max_scar_fraction={max_scar_fraction})"
            )
    union = np.logical_or.reduce([c | b for c, b in regions]) if regions else np.zeros(n, bool)
    if union.sum() > limit:
        raise TissueError(
            f"scars 0..{len(regions) - 1}: whole-heart scar, together they cover "
            f"{union.mean():.1%} of the nodes (max_scar_fraction={max_scar_fraction})"
        )

    # Borders first, then cores, so a core always overrides a border.
    for scar, (_, border) in zip(spec.scars, regions):
        _paint(border, scar.border, LABEL_BORDER, a, D, label)
    for scar, (core, _) in zip(spec.scars, regions):
        _paint(core, scar.core, LABEL_CORE, a, D, label)
    if not D.any():
        raise TissueError(
            f"tissue {spec.name!r}: D = 0 at every node of mesh {mesh.name!r}, so no wave can propagate; "
            "give the healthy material (or a scar) a diffusivity scale D > 0"
        )
    return TissueFields(a=a, D=D, label=label)


def _paint(
    mask: NDArray[np.bool_],
    mat: Material,
    lab: int,
    a: NDArray[np.float64],
    D: NDArray[np.float64],
    label: NDArray[np.int8],
) -> None:
    """Set ``mat`` and ``lab`` on ``mask`` in place where ``mat`` beats what is there.

    ``mat`` beats any other label, and within label ``lab`` a material with a
    lower ``a`` (ties: a higher ``D``).
    """
    beats = (mat.a > a) | ((mat.a == a) & (mat.D < D))
    take = mask & ((label != lab) | beats)
    a[take], D[take], label[take] = mat.a, mat.D, lab
