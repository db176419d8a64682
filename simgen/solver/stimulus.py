"""Stimulus patches: the nodes excited at t = 0 around each stimulation site.

Two shapes of patch, both of a radius in mm (:data:`STIMULUS_REGIONS`):

- ``"ball"`` (the default): the tissue within Euclidean distance ``radius`` of
  the site, the part of it connected to the site inside the ball (so a patch
  on one wall never reaches across a cavity to another). As the mesh is
  refined the nodes it holds fill the same ball, whatever the resolution.
- ``"geodesic"``: the nodes within ``radius`` of the site along mesh edges.
  An edge path zigzags, and more so on a coarse mesh, so the patch shrinks as
  the mesh coarsens; stores built before the ball existed used it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order, dijkstra

from shared.errors import StimulusError
from shared.fem import lumped_mass
from shared.mesh import Mesh
from shared.tissue import LABEL_HEALTHY
from simgen.meshes.topology import edge_graph

__all__ = ["IN_SCAR", "RESOLVED_SCAR_EDGE", "STIMULUS_REGIONS", "check_sites", "patch_mask", "scar_share"]

#: Shapes of stimulus patch; the first is the default.
STIMULUS_REGIONS = ("ball", "geodesic")
#: A site is paced in a scar when at least this share of its patch's volume lies in a scar's core or border zone.
IN_SCAR = 0.5
#: Mean edge (mm) up to which a wave leaving a scar from a site paced in it converges under mesh refinement
#: (docs/method.md, "Convergence under mesh refinement"; outside scars results converge on coarser meshes).
RESOLVED_SCAR_EDGE = 4.5


def check_sites(mesh: Mesh, sites: NDArray[np.integer]) -> NDArray[np.int64]:
    """Validate stimulation node ids (integers in ``[0, N)``) and return them as int64."""
    arr = np.asarray(sites)
    if arr.ndim != 1 or arr.size == 0:
        raise StimulusError(f"stimulation sites must be a non-empty 1-D list of node ids, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise StimulusError(f"stimulation sites must be integer node ids, got dtype {arr.dtype}")
    bad = arr[(arr < 0) | (arr >= mesh.n_nodes)]
    if bad.size:
        raise StimulusError(
            f"unknown stimulation node(s) {bad[:5].tolist()}: mesh {mesh.name!r} has nodes 0..{mesh.n_nodes - 1}"
        )
    return arr.astype(np.int64)


def patch_mask(
    mesh: Mesh,
    sites: NDArray[np.integer],
    radius: float,
    graph: sp.csr_matrix | None = None,
    region: str = STIMULUS_REGIONS[0],
    centres: NDArray[np.floating] | None = None,
) -> NDArray[np.bool_]:
    """Boolean (N, S) mask of the nodes each site's stimulus excites: its patch of ``radius`` mm.

    ``region``: ``"ball"`` or ``"geodesic"`` (module docstring). The site
    itself is always included, so ``radius = 0`` excites one node.
    ``graph``: ``edge_graph(mesh)`` if the caller keeps it (built otherwise).
    ``centres``: (S, 3) points (mm) the balls are centred on, for sites given
    by position (each site is then the node nearest its point); ``None``: the
    sites' nodes.
    """
    sites = check_sites(mesh, sites)
    if not np.isfinite(radius) or radius < 0:
        raise StimulusError(f"stimulus radius must be >= 0 mm, got {radius}")
    if region not in STIMULUS_REGIONS:
        raise StimulusError(f"unknown stimulus region {region!r}; use one of {list(STIMULUS_REGIONS)}")
    graph = edge_graph(mesh) if graph is None else graph
    limit = radius * (1 + 1e-9)
    if region == "geodesic":
        if centres is not None:
            raise StimulusError("geodesic stimulus patches start at a node: give sites, not centres")
        unique, inverse = np.unique(sites, return_inverse=True)
        dist = dijkstra(graph, directed=False, indices=unique, limit=limit)
        return (dist <= limit).T[:, inverse]
    centres = mesh.points[sites] if centres is None else np.asarray(centres, np.float64)
    if centres.shape != (len(sites), 3) or not np.isfinite(centres).all():
        raise StimulusError(f"centres must be {len(sites)} finite points (S, 3), got shape {centres.shape}")
    mask = np.zeros((mesh.n_nodes, len(sites)), bool)
    for column, (site, centre) in enumerate(zip(sites, centres)):
        inside = np.flatnonzero(np.linalg.norm(mesh.points - centre, axis=1) <= limit)
        inside = np.union1d(inside, [site])
        start = int(np.searchsorted(inside, site))
        reached = breadth_first_order(graph[inside][:, inside], start, directed=False, return_predecessors=False)
        mask[inside[reached], column] = True
    return mask


def scar_share(mesh: Mesh, label: NDArray[np.integer], mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(S,) share of each stimulus patch of ``mask`` (N, S) (:func:`patch_mask`) that lies in a scar's core or
    border zone (``label`` not healthy), its nodes weighted by their lumped mass (volume)."""
    mass = lumped_mass(mesh)
    return ((mass * (np.asarray(label) != LABEL_HEALTHY)) @ mask) / np.maximum(mass @ mask, np.finfo(float).tiny)
