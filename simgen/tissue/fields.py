"""Per-node tissue fields (excitability ``a``, diffusivity scale ``D``, label) from a spec.

Each scar has a *core* (its region: AHA segments, a Euclidean ball, or an
ellipsoid in a ventricle's wall placed in the heart's own coordinates,
:class:`~shared.tissue.ScarSpec`) and a *border zone*: the non-core nodes within ``border_width`` mm of the core,
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

Overlaps: a core beats any border, a border beats fibrosis; among cores,
and among borders, the material with the higher ``a`` wins (ties: the lower
``D``). Diffuse fibrosis (:class:`~shared.tissue.FibrosisSpec`) is painted
first, on the patches of a seeded Voronoi field in space (:func:`fibrosis_mask`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from shared.errors import TissueError
from shared.mesh import Mesh
from shared.tissue import (
    LABEL_BORDER,
    LABEL_CORE,
    LABEL_FIBROSIS,
    LABEL_HEALTHY,
    FibrosisSpec,
    Material,
    ScarSpec,
    TissueFields,
    TissueSpec,
)
from simgen.meshes.aha import aha_segments, estimate_axis, longitudinal_angular
from simgen.meshes.fibres import laplace
from simgen.meshes.topology import edge_graph

__all__ = ["SCAR_BORDERS", "tissue_fields", "scar_regions", "fibrosis_mask", "wall_centre"]

#: Most Voronoi points a fibrosis pattern spreads over a mesh's bounding box.
MAX_PATCHES = 2_000_000

#: Where a border zone's width is measured from; the first is the default (module docstring).
SCAR_BORDERS = ("boundary", "nodes")


class _Frame:
    """What placing wall scars on one mesh needs, computed once: heights, angles, the long axis and the
    transmural coordinate (volume meshes with an endocardium and an epicardium; else ``None``)."""

    def __init__(self, mesh: Mesh) -> None:
        self.axis = mesh.axis if mesh.axis is not None else estimate_axis(mesh)
        self.edge = mesh.mean_edge_length()
        self.height, self.angle = longitudinal_angular(mesh)
        offset = mesh.points - np.asarray(self.axis.apex)
        along = offset @ self.axis.direction
        self.radial = np.linalg.norm(offset - along[:, None] * self.axis.direction, axis=1)
        sets = mesh.node_sets
        self.transmural = None
        if mesh.cell_type == "tetra" and "endocardium" in sets and "epicardium" in sets:
            self.transmural = laplace(mesh, {0.0: mesh.nodes("endocardium"), 1.0: mesh.nodes("epicardium")})


def wall_centre(mesh: Mesh, scar: ScarSpec, frame: _Frame | None = None) -> int | None:
    """The node a ``region = "wall"`` scar is centred on, or ``None`` where the mesh lacks its ventricle.

    Among the ventricle's endocardial nodes (``lv_endocardium`` or, on an LV, ``endocardium``;
    ``rv_endocardium``) those within 2 mm, or 1.5 mean edges, of the nearest to the scar's height and
    angle (distances in mm along the wall: height times the axis length, angle times the distance from
    the axis); of these the nearest, or on the RV the one farthest from the axis (the free wall, not the
    septum's RV face). A mesh without endocardial node sets places an LV scar on its surface.
    """
    frame = frame or _Frame(mesh)
    rv = scar.ventricle == "rv"
    name = "rv_endocardium" if rv else ("lv_endocardium" if "lv_endocardium" in mesh.node_sets else "endocardium")
    if name not in mesh.node_sets:
        if rv:
            return None
        name = "surface"
    nodes = np.unique(mesh.nodes(name))
    turn = np.radians((frame.angle[nodes] - scar.angle + 180.0) % 360.0 - 180.0)
    apart = np.hypot((frame.height[nodes] - scar.height) * frame.axis.length, turn * frame.radial[nodes])
    near = nodes[apart <= apart.min() + max(2.0, 1.5 * frame.edge)]
    if rv:
        return int(near[np.argmax(frame.radial[near])])
    return int(nodes[np.argmin(apart)])


def _wall_core(mesh: Mesh, scar: ScarSpec, frame: _Frame) -> NDArray[np.bool_] | None:
    """The nodes of a wall scar's ellipsoid (``None``: its ventricle is not in the mesh)."""
    centre = wall_centre(mesh, scar, frame)
    if centre is None:
        return None
    d = frame.axis.direction
    offset = mesh.points - mesh.points[centre]
    radial = mesh.points[centre] - np.asarray(frame.axis.apex)
    radial -= (radial @ d) * d
    radial /= max(np.linalg.norm(radial), 1e-12)
    around = np.cross(d, radial)
    long_axis = scar.radius * (scar.elongation or 1.0)
    inside = ((offset @ d) / long_axis) ** 2 + ((offset @ radial) ** 2 + (offset @ around) ** 2) / scar.radius**2 <= 1
    if frame.transmural is not None and scar.transmural is not None:
        inside &= frame.transmural <= scar.transmural
    inside[centre] = True
    return inside


def _core(
    mesh: Mesh, scar: ScarSpec, index: int, segments: NDArray[np.int8] | None, frame: _Frame | None
) -> NDArray[np.bool_] | None:
    if scar.region == "segments":
        assert segments is not None
        core = np.isin(segments, np.asarray(scar.segments, dtype=np.int8))
        what = f"AHA segments {list(scar.segments)}"
    elif scar.region == "wall":
        assert frame is not None
        core = _wall_core(mesh, scar, frame)
        if core is None:
            if scar.optional:
                return None
            raise TissueError(
                f"scar {index}: a wall scar in the RV, and mesh {mesh.name!r} has no rv_endocardium "
                "(set optional = true to leave such a scar out)"
            )
        what = f"wall ellipsoid at height {scar.height:g}, angle {scar.angle:g} deg"
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
    """``(core, border)`` boolean node masks of every scar, before overlap rules; an optional wall scar in a
    ventricle the mesh lacks has two empty masks.

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
    frame = _Frame(mesh) if any(s.region == "wall" for s in spec.scars) else None
    if graph is None and any(s.border_width > 0 for s in spec.scars):
        graph = edge_graph(mesh)
    regions = []
    for i, scar in enumerate(spec.scars):
        core = _core(mesh, scar, i, segments, frame)
        if core is None:
            regions.append((np.zeros(mesh.n_nodes, bool), np.zeros(mesh.n_nodes, bool)))
            continue
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
    (0 healthy, 1 border zone, 2 core, 3 fibrosis).

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

    if spec.fibrosis is not None:
        _paint(fibrosis_mask(mesh, spec.fibrosis), spec.fibrosis.material, LABEL_FIBROSIS, a, D, label)
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

    ``mat`` beats any other label (the callers paint fibrosis, then borders, then cores), and within label
    ``lab`` a material with a higher ``a`` (ties: a lower ``D``).
    """
    beats = (mat.a > a) | ((mat.a == a) & (mat.D < D))
    take = mask & ((label != lab) | beats)
    a[take], D[take], label[take] = mat.a, mat.D, lab


def _cell_hash(cells: NDArray[np.int64], seed: int, stream: int) -> NDArray[np.float64]:
    """Uniform numbers in [0, 1) from integer lattice cells (K, 3), the seed and a stream number: a
    splitmix64 mix of the three indices, so a cell's numbers depend on the cell alone, not on which
    others a mesh's bounding box holds."""
    with np.errstate(over="ignore"):
        h = np.full(len(cells), np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(stream))
        for axis in range(3):
            h ^= cells[:, axis].astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15) + (h << np.uint64(6))
            h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def fibrosis_mask(mesh: Mesh, fibrosis: FibrosisSpec) -> NDArray[np.bool_]:
    """The fibrotic nodes of ``fibrosis`` on ``mesh``: each node takes the patch of its nearest point of a
    lattice of spacing ``patch`` mm anchored at the origin, each point jittered within its cell, and a patch
    is fibrotic with probability ``density``. Jitter and draw come from the cell's indices and
    ``fibrosis.seed`` alone, so the pattern lies in space: the same on every mesh of one heart."""
    lo = np.floor(mesh.points.min(axis=0) / fibrosis.patch).astype(np.int64) - 1
    hi = np.floor(mesh.points.max(axis=0) / fibrosis.patch).astype(np.int64) + 1
    shape = hi - lo + 1
    if int(np.prod(shape)) > MAX_PATCHES:
        raise TissueError(
            f"fibrosis patch size {fibrosis.patch:g} mm is too small for mesh {mesh.name!r} "
            f"({int(np.prod(shape)):,} patches, at most {MAX_PATCHES:,})"
        )
    cells = lo + np.stack(np.meshgrid(*(np.arange(k) for k in shape), indexing="ij"), axis=-1).reshape(-1, 3)
    jitter = np.stack([_cell_hash(cells, fibrosis.seed, axis) for axis in range(3)], axis=1)
    fibrotic = _cell_hash(cells, fibrosis.seed, 3) < fibrosis.density
    return fibrotic[cKDTree((cells + jitter) * fibrosis.patch).query(mesh.points)[1]]
