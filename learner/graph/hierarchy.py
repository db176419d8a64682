"""Mesh graphs and their coarsening hierarchy (graph-Voronoi clustering), with pooling operators.

Level 0 is the mesh itself; each further level clusters the previous level's
graph into connected clusters. Pooling averages a signal over each cluster,
unpooling copies a cluster's value back to its members:

.. math::

    (\\mathrm{pool}\\,x)_c = \\frac{1}{|c|}\\sum_{i \\in c} x_i, \\qquad
    (\\mathrm{unpool}\\,y)_i = y_{a(i)}

with :math:`a(i)` the cluster of node :math:`i` (``MeshHierarchy.assign``).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree
from torch import Tensor

from learner.graph.working import WorkingMap
from shared.errors import InputError, MeshError
from shared.graph import edge_length_graph, undirected_edges
from shared.mesh import Mesh

__all__ = [
    "Graph",
    "MeshHierarchy",
    "build_hierarchy",
    "cluster_graph",
    "midpoint_graph",
    "working_clusters",
    "hierarchy_for_mesh",
]

#: Bump when the clustering changes, so cached hierarchies are rebuilt.
ALGORITHM_VERSION = 3
#: A mesh of fewer nodes than this per working node is clustered on its midpoint-refined graph
#: (:func:`working_clusters`); the shipped model's training meshes hold 10-20.
REFINE_BELOW = 8
#: Lloyd relaxations after farthest-point seeding.
LLOYD_ITERATIONS = 3
_FILE_FORMAT = 1
#: Hierarchies :func:`hierarchy_for_mesh` keeps in memory (least recently used dropped first).
RECENT_HIERARCHIES = 4
_RECENT: OrderedDict[str, MeshHierarchy] = OrderedDict()


@dataclass(frozen=True, eq=False)
class Graph:
    """A directed graph with edges both ways and Cartesian edge attributes.

    Parameters
    ----------
    edge_index : (2, E) long; row 0 the source ``j``, row 1 the target ``i``
        (a message flows ``j -> i``). Sorted by target, then source.
    pseudo : (E, 3) float in [0, 1],
        :math:`(p_j - p_i) / (2 \\max_{e,d} |p_j - p_i|_d) + 1/2` (PyG
        ``Cartesian(norm=True)``: one maximum over the whole graph).
    num_nodes : number of nodes ``N``.
    positions : (N, 3) float node coordinates.
    """

    edge_index: Tensor
    pseudo: Tensor
    num_nodes: int
    positions: Tensor

    def __post_init__(self) -> None:
        ei, ps, pos = self.edge_index, self.pseudo, self.positions
        if ei.dim() != 2 or ei.shape[0] != 2 or ei.dtype != torch.long:
            raise InputError(f"edge_index must be a (2, E) long tensor, got {tuple(ei.shape)} {ei.dtype}")
        if ps.dim() != 2 or ps.shape[0] != ei.shape[1]:
            raise InputError(f"pseudo must have shape (E={ei.shape[1]}, D), got {tuple(ps.shape)}")
        if pos.dim() != 2 or pos.shape[0] != self.num_nodes:
            raise InputError(f"positions must have shape (N={self.num_nodes}, 3), got {tuple(pos.shape)}")
        if ei.numel() and (int(ei.min()) < 0 or int(ei.max()) >= self.num_nodes):
            raise InputError(f"edge_index has node ids outside [0, {self.num_nodes})")

    @property
    def num_edges(self) -> int:
        """Number of directed edges ``E``."""
        return int(self.edge_index.shape[1])

    @classmethod
    def from_edges(cls, points: NDArray[np.floating], edges: NDArray[np.integer]) -> Graph:
        """The graph of undirected ``edges`` (E, 2) over ``points`` (N, 3), both directions, sorted."""
        points = np.asarray(points, dtype=np.float64)
        und = undirected_edges(edges, len(points))
        src = np.concatenate([und[:, 0], und[:, 1]])
        dst = np.concatenate([und[:, 1], und[:, 0]])
        # target-major order keeps the scatter in SplineConv cache-friendly
        order = np.lexsort((src, dst))
        src, dst = src[order], dst[order]
        cart = points[src] - points[dst]
        peak = np.abs(cart).max() if cart.size else 0.0
        pseudo = cart / (2.0 * peak) + 0.5 if peak > 0 else np.full_like(cart, 0.5)
        return cls(
            edge_index=torch.from_numpy(np.stack([src, dst]).astype(np.int64)),
            pseudo=torch.from_numpy(np.clip(pseudo, 0.0, 1.0).astype(np.float32)),
            num_nodes=len(points),
            positions=torch.from_numpy(points.astype(np.float32)),
        )

    def to(self, device: torch.device | str) -> Graph:
        """A copy with every tensor on ``device``."""
        return Graph(self.edge_index.to(device), self.pseudo.to(device), self.num_nodes, self.positions.to(device))

    def __repr__(self) -> str:
        return f"Graph(num_nodes={self.num_nodes}, num_edges={self.num_edges})"


@dataclass(frozen=True, eq=False)
class MeshHierarchy:
    """Graphs from fine (level 0, the mesh nodes) to coarse, and the cluster map between levels.

    Parameters
    ----------
    graphs : one :class:`Graph` per level.
    assign : ``assign[l]`` (n_l,) long maps each level-``l`` node to its
        level-``l+1`` cluster; one entry per level but the last.
    working : how the mesh's nodes map onto level 0 when level 0 is a working
        graph of clusters of them (:mod:`learner.graph.working`); ``None``:
        level 0 is the mesh itself.
    """

    graphs: tuple[Graph, ...]
    assign: tuple[Tensor, ...]
    working: WorkingMap | None = None

    def __post_init__(self) -> None:
        graphs, assign = tuple(self.graphs), tuple(self.assign)
        object.__setattr__(self, "graphs", graphs)
        object.__setattr__(self, "assign", assign)
        if len(graphs) < 1 or len(assign) != len(graphs) - 1:
            raise InputError(f"a hierarchy needs n levels and n - 1 maps, got {len(graphs)} and {len(assign)}")
        for lvl, a in enumerate(assign):
            n, m = graphs[lvl].num_nodes, graphs[lvl + 1].num_nodes
            if a.shape != (n,) or a.dtype != torch.long:
                raise InputError(f"assign[{lvl}] must be a ({n},) long tensor, got {tuple(a.shape)} {a.dtype}")
            if n and (int(a.min()) < 0 or int(a.max()) >= m):
                raise InputError(f"assign[{lvl}] has cluster ids outside [0, {m})")
        if self.working is not None and self.working.working_nodes != graphs[0].num_nodes:
            raise InputError(
                f"the working map ends on {self.working.working_nodes} nodes, level 0 has {graphs[0].num_nodes}"
            )

    @property
    def n_levels(self) -> int:
        return len(self.graphs)

    @property
    def sizes(self) -> tuple[int, ...]:
        """Number of nodes per level, fine to coarse."""
        return tuple(g.num_nodes for g in self.graphs)

    @property
    def mesh_nodes(self) -> int:
        """Nodes of the mesh the hierarchy stands for: level 0's, or the working map's mesh."""
        return self.sizes[0] if self.working is None else self.working.mesh_nodes

    def level0_sites(self, nodes: Tensor) -> Tensor:
        """The level-0 node of each mesh node in ``nodes``: itself, or its working cluster."""
        return nodes.long() if self.working is None else self.working.sites(nodes)

    def level0_observations(self, obs: Tensor, observed: Tensor) -> tuple[Tensor, Tensor]:
        """Observed mesh sequences ``(K, T, N)`` and mask, ``(N,)`` or per value ``(K, T, N)``, at level 0
        (unchanged without a working map)."""
        return (obs, observed) if self.working is None else self.working.observations(obs, observed)

    def to_mesh(self, x: Tensor) -> Tensor:
        """A level-0 field ``(..., n_0)`` at the mesh's nodes (unchanged without a working map)."""
        return x if self.working is None else self.working.expand(x)

    def _check_level(self, level: int, what: str) -> None:
        if not 0 <= level < self.n_levels - 1:
            raise InputError(f"{what}: level must be in [0, {self.n_levels - 1}), got {level}")

    def _check_x(self, x: Tensor, level: int, nodes: int, what: str) -> None:
        if x.dim() != 3 or x.shape[1] != nodes:
            raise InputError(f"{what} at level {level} expects (B, {nodes}, C), got {tuple(x.shape)}")

    def pool(self, x: Tensor, level: int) -> Tensor:
        """Mean over clusters: ``(B, n_l, C) -> (B, n_{l+1}, C)``."""
        self._check_level(level, "pool")
        self._check_x(x, level, self.sizes[level], "pool")
        a = self.assign[level]
        m = self.sizes[level + 1]
        count = torch.bincount(a, minlength=m).clamp_(min=1).to(x.dtype)
        cols = x.permute(1, 2, 0)
        if cols.is_contiguous():  # a view of the (N, C, B) inference layout: add whole node rows
            total = x.new_zeros(m, x.shape[2], x.shape[0]).index_add_(0, a, cols)
            return (total / count.view(m, 1, 1)).permute(2, 0, 1)
        total = x.new_zeros(x.shape[0], m, x.shape[2]).index_add_(1, a, x)
        return total / count.view(1, m, 1)

    def unpool(self, x: Tensor, level: int) -> Tensor:
        """Copy each cluster's value to its members: ``(B, n_{l+1}, C) -> (B, n_l, C)``."""
        self._check_level(level, "unpool")
        self._check_x(x, level, self.sizes[level + 1], "unpool")
        cols = x.permute(1, 2, 0)
        if cols.is_contiguous():  # a view of the (N, C, B) inference layout: copy whole node rows (8x faster)
            return cols.index_select(0, self.assign[level]).permute(2, 0, 1)
        return x.index_select(1, self.assign[level])

    def coarsest_cluster(self, nodes: Tensor) -> Tensor:
        """The coarsest-level node that each mesh node of ``nodes`` (long) belongs to."""
        for a in self.assign:
            nodes = a[nodes]
        return nodes

    def pool_matrix(self, level: int, dtype: torch.dtype = torch.float32) -> Tensor:
        """Sparse COO ``(n_{l+1}, n_l)`` matrix ``P`` with ``pool(x)[b] == P @ x[b]``."""
        self._check_level(level, "pool_matrix")
        a = self.assign[level]
        m, n = self.sizes[level + 1], self.sizes[level]
        count = torch.bincount(a, minlength=m).clamp_(min=1).to(dtype)
        idx = torch.stack([a, torch.arange(n, device=a.device)])
        return torch.sparse_coo_tensor(idx, 1.0 / count[a], (m, n), check_invariants=False).coalesce()

    def unpool_matrix(self, level: int, dtype: torch.dtype = torch.float32) -> Tensor:
        """Sparse COO ``(n_l, n_{l+1})`` matrix ``U`` with ``unpool(y)[b] == U @ y[b]``."""
        self._check_level(level, "unpool_matrix")
        a = self.assign[level]
        m, n = self.sizes[level + 1], self.sizes[level]
        idx = torch.stack([torch.arange(n, device=a.device), a])
        ones = torch.ones(n, dtype=dtype, device=a.device)
        return torch.sparse_coo_tensor(idx, ones, (n, m), check_invariants=False).coalesce()

    def to(self, device: torch.device | str) -> MeshHierarchy:
        """A copy with every tensor on ``device``."""
        working = None if self.working is None else self.working.to(device)
        return MeshHierarchy(
            tuple(g.to(device) for g in self.graphs), tuple(a.to(device) for a in self.assign), working
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """Every tensor as a named array (:meth:`from_arrays` inverts it; :meth:`save` writes them)."""
        arrays: dict[str, np.ndarray] = {"format": np.array(_FILE_FORMAT), "n_levels": np.array(self.n_levels)}
        for lvl, g in enumerate(self.graphs):
            arrays[f"edge_index_{lvl}"] = g.edge_index.cpu().numpy()
            arrays[f"pseudo_{lvl}"] = g.pseudo.cpu().numpy()
            arrays[f"positions_{lvl}"] = g.positions.cpu().numpy()
        for lvl, a in enumerate(self.assign):
            arrays[f"assign_{lvl}"] = a.cpu().numpy()
        if self.working is not None:
            arrays.update({f"working_{key}": value for key, value in self.working.arrays().items()})
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], where: str = "mesh hierarchy") -> MeshHierarchy:
        """The hierarchy of :meth:`arrays`; :class:`InputError` naming ``where`` for a wrong or partial set."""
        if "format" not in arrays or int(arrays["format"]) != _FILE_FORMAT:
            raise InputError(f"{where} is not a mesh hierarchy of format {_FILE_FORMAT}")
        try:
            n = int(arrays["n_levels"])
            graphs = tuple(
                Graph(
                    edge_index=torch.from_numpy(np.asarray(arrays[f"edge_index_{lvl}"]).astype(np.int64)),
                    pseudo=torch.from_numpy(np.asarray(arrays[f"pseudo_{lvl}"])),
                    num_nodes=len(arrays[f"positions_{lvl}"]),
                    positions=torch.from_numpy(np.asarray(arrays[f"positions_{lvl}"])),
                )
                for lvl in range(n)
            )
            assign = tuple(
                torch.from_numpy(np.asarray(arrays[f"assign_{lvl}"]).astype(np.int64)) for lvl in range(n - 1)
            )
        except KeyError as exc:
            raise InputError(f"{where} lacks array {exc}") from None
        working = {key.removeprefix("working_"): v for key, v in arrays.items() if key.startswith("working_")}
        return cls(graphs, assign, WorkingMap.from_arrays(working) if working else None)

    def save(self, path: str | Path) -> None:
        """Write :meth:`arrays` to ``path`` as an ``.npz`` archive (atomically: a reader never sees half a file)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **self.arrays())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: str | Path) -> MeshHierarchy:
        """Read a hierarchy written by :meth:`save`."""
        try:
            with np.load(Path(path), allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise InputError(f"{path} is not a readable mesh hierarchy file: {exc}") from None
        return cls.from_arrays(arrays, str(path))

    def __repr__(self) -> str:
        mesh = "" if self.working is None else f", mesh_nodes={self.mesh_nodes}"
        return f"MeshHierarchy(sizes={self.sizes}{mesh})"


def _farthest_point_seeds(adj: csr_matrix, k: int) -> NDArray[np.int64]:
    """``k`` seeds by farthest-point sampling in graph distance, starting at node 0."""
    mind = dijkstra(adj, directed=True, indices=0)
    seeds = [0]
    for _ in range(k - 1):
        s = int(np.argmax(mind))
        seeds.append(s)
        # only nodes nearer to s than the current maximum can change
        d = dijkstra(adj, directed=True, indices=s, limit=float(mind[s]))
        np.minimum(mind, d, out=mind)
    return np.asarray(seeds, dtype=np.int64)


def _voronoi(adj: csr_matrix, seeds: NDArray[np.int64]) -> NDArray[np.int64]:
    """Cluster (index into ``seeds``) of every node: its nearest seed in graph distance.

    Each node follows its shortest-path tree to its seed, so clusters are connected.
    """
    _, _, sources = dijkstra(adj, directed=True, indices=seeds, min_only=True, return_predecessors=True)
    lookup = np.full(adj.shape[0], -1, dtype=np.int64)
    lookup[seeds] = np.arange(len(seeds))
    return lookup[sources]


def _cluster(points: NDArray[np.float64], und: NDArray[np.int64], k: int) -> NDArray[np.int64]:
    """Connected clusters 0..k'-1 (k' <= k, empty ones dropped) of a connected graph."""
    adj = edge_length_graph(points, und)
    seeds = _farthest_point_seeds(adj, k)
    assign = _voronoi(adj, seeds)
    for _ in range(LLOYD_ITERATIONS):
        count = np.bincount(assign, minlength=k).astype(np.float64)
        centroid = np.stack([np.bincount(assign, points[:, d], minlength=k) for d in range(3)], axis=1)
        centroid /= np.maximum(count, 1.0)[:, None]
        d2 = ((points - centroid[assign]) ** 2).sum(axis=1)
        order = np.lexsort((d2, assign))  # by cluster, then distance to its centroid
        first = np.flatnonzero(np.r_[True, np.diff(assign[order]) != 0])
        new = np.full(k, -1, dtype=np.int64)
        new[assign[order[first]]] = order[first]
        seeds = new[new >= 0]
        assign = _voronoi(adj, seeds)
    _, assign = np.unique(assign, return_inverse=True)  # drop empty clusters, keep order
    return assign.astype(np.int64)


def _level_sizes(n: int, levels: int, coarsest: int) -> list[int]:
    """Geometric sizes :math:`N (c/N)^{l/(L-1)}` from ``n`` down to ``coarsest``."""
    return [int(round(n * (coarsest / n) ** (lvl / (levels - 1)))) for lvl in range(levels)]


def build_hierarchy(
    points: NDArray[np.floating], edges: NDArray[np.integer], levels: int = 5, coarsest: int = 40
) -> MeshHierarchy:
    """Coarsen a connected mesh graph into ``levels`` levels by graph-Voronoi clustering.

    Level sizes are geometric from ``N`` to ``coarsest``. Each coarsening seeds
    clusters by farthest-point sampling (graph distance, edge-length weighted,
    from node 0), assigns nodes to the nearest seed, then runs a few Lloyd steps
    (new seed = the member nearest its cluster's centroid). Coarse nodes sit at
    their members' mean; two clusters are joined when any fine edge joins them.
    Deterministic.

    Parameters
    ----------
    points : (N, 3) node coordinates.
    edges : (E, 2) undirected edges (duplicates and self loops are ignored).
    levels : number of levels including the mesh itself (>= 2).
    coarsest : target size of the last level (1 <= coarsest < N).
    """
    points = np.asarray(points, dtype=np.float64)
    edges = np.asarray(edges)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise MeshError("points contain non-finite coordinates")
    n = len(points)
    if int(levels) != levels or levels < 2:
        raise InputError(f"levels must be an integer >= 2, got {levels}")
    if int(coarsest) != coarsest or not 1 <= coarsest < n:
        raise InputError(f"coarsest must be an integer in [1, N={n}), got {coarsest}")
    levels, coarsest = int(levels), int(coarsest)
    und = undirected_edges(edges, n)
    n_comp, _ = connected_components(edge_length_graph(points, und), directed=False)
    if n_comp != 1:
        raise MeshError(f"the mesh graph has {n_comp} connected components; a hierarchy needs a connected mesh")

    sizes = _level_sizes(n, levels, coarsest)
    pos, graphs, assign = points, [Graph.from_edges(points, und)], []
    for target in sizes[1:]:
        a, pos, und = cluster_graph(pos, und, target)
        assign.append(torch.from_numpy(a))
        graphs.append(Graph.from_edges(pos, und))
    return MeshHierarchy(tuple(graphs), tuple(assign))


def working_clusters(
    points: NDArray[np.float64], edges: NDArray[np.int64], k: int, cells: NDArray[np.int64] | None = None
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """A mesh's working graph of ``k`` clusters: ``(assign, positions, edges)`` (:mod:`learner.graph.working`).

    Seeds by farthest-point sampling in graph distance, each node in the
    cluster of its nearest seed; a working node sits at its seed, a mesh node.
    Unlike the hierarchy's coarser levels (Lloyd-relaxed, at the members'
    mean) it keeps the seeds where farthest-point sampling puts them: on a
    thin wall mostly on its two surfaces, as the nodes of a coarse mesh are,
    whether a cluster holds 2 nodes or 40. Centred clusters sit mid-wall on a
    fine mesh and on the surfaces of a coarse one, a different graph.

    With ``cells``, a mesh of fewer than :data:`REFINE_BELOW` nodes per
    cluster is clustered on its midpoint-refined graph
    (:func:`midpoint_graph`), whose seeds spread as on a finer mesh of the
    same shape (on a mesh of 2 nodes per cluster the seeds would be every
    other node); its nodes keep their clusters, and a cluster may then hold
    midpoints only.
    """
    n = len(points)
    if cells is not None and n < REFINE_BELOW * k:
        fine_points, fine_edges = midpoint_graph(points, edges, cells)
        assign, positions, working = working_clusters(fine_points, fine_edges, k)
        return assign[:n], positions, working
    adj = edge_length_graph(points, edges)
    seeds = _farthest_point_seeds(adj, k)
    assign = _voronoi(adj, seeds)  # every seed is its own cluster's: none is empty
    return assign, points[seeds], undirected_edges(assign[edges], k)


def midpoint_graph(
    points: NDArray[np.float64], edges: NDArray[np.int64], cells: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The graph of a mesh refined once: ``(points, edges)`` with each edge's midpoint added after the
    nodes (in the order of :func:`undirected_edges`), each midpoint joined to its edge's two ends and to
    the other midpoints of every cell holding its edge."""
    n = len(points)
    und = undirected_edges(edges, n)
    codes = und[:, 0] * n + und[:, 1]  # sorted: undirected_edges returns unique sorted pairs
    first, second = np.triu_indices(cells.shape[1], k=1)  # each cell's edges as pairs of its corners
    ends = np.sort(np.stack([cells[:, first], cells[:, second]], axis=2), axis=2)
    mid = n + np.searchsorted(codes, ends[..., 0] * n + ends[..., 1])  # (M, edges per cell) midpoint ids
    m = np.arange(len(und)) + n
    links = [np.stack([und[:, 0], m], 1), np.stack([und[:, 1], m], 1)]
    p, q = np.triu_indices(mid.shape[1], k=1)
    links.append(np.stack([mid[:, p], mid[:, q]], axis=2).reshape(-1, 2))
    fine_points = np.concatenate([points, 0.5 * (points[und[:, 0]] + points[und[:, 1]])])
    return fine_points, undirected_edges(np.concatenate(links), len(fine_points))


def cluster_graph(
    points: NDArray[np.float64], edges: NDArray[np.int64], k: int
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """One coarsening of a connected graph into at most ``k`` clusters: ``(assign, centres, edges)``.

    ``assign`` (N,) the cluster of each node (:func:`build_hierarchy` describes
    the clustering); ``centres`` (k', 3) each cluster's mean position; ``edges``
    the unique undirected pairs of clusters joined by an edge of ``edges``.
    """
    a = _cluster(points, edges, min(k, len(points)))
    m = int(a.max()) + 1
    count = np.bincount(a, minlength=m)
    centres = np.stack([np.bincount(a, points[:, d], minlength=m) for d in range(3)], axis=1) / count[:, None]
    return a, centres, undirected_edges(a[edges], m)


def _cache_key(mesh: Mesh, levels: int, coarsest: int, working_nodes: int | None) -> str:
    h = hashlib.sha256()
    working = "" if working_nodes is None else f" working={working_nodes}"
    h.update(f"hierarchy v{ALGORITHM_VERSION} levels={levels} coarsest={coarsest}{working};".encode())
    for arr in (np.ascontiguousarray(mesh.points, np.float64), np.ascontiguousarray(mesh.cells, np.int32)):
        h.update(f"{arr.shape};".encode())
        h.update(arr.tobytes())
    return h.hexdigest()[:24]


def hierarchy_for_mesh(
    mesh: Mesh,
    levels: int = 5,
    coarsest: int = 40,
    cache_dir: str | Path | None = None,
    working_nodes: int | None = None,
) -> MeshHierarchy:
    """:func:`build_hierarchy` on a mesh's edges, cached in ``cache_dir`` (None: no cache).

    ``working_nodes``: a mesh of more nodes is first clustered into that many,
    its working graph (:mod:`learner.graph.working`), and the hierarchy built
    on that graph with the map from the mesh attached; ``None``, or a mesh of
    at most that many nodes: the hierarchy of the mesh itself.

    The cache file is keyed by a hash of the points, cells, ``levels``,
    ``coarsest`` and ``working_nodes`` (and the algorithm version); an
    unreadable file is rebuilt. Without ``cache_dir`` the last
    :data:`RECENT_HIERARCHIES` are kept in memory under the same key, so
    personalising one mesh again (a user's mesh of 100,000 nodes takes
    seconds to cluster) builds nothing.
    """
    if working_nodes is not None and mesh.n_nodes <= working_nodes and len(np.unique(mesh.cells)) == mesh.n_nodes:
        working_nodes = None  # a mesh of every node in a cell, no finer than the working graph: as it is
    key = _cache_key(mesh, levels, coarsest, working_nodes)
    if cache_dir is None:
        if key not in _RECENT:
            _RECENT[key] = _hierarchy(mesh, levels, coarsest, working_nodes)
            while len(_RECENT) > RECENT_HIERARCHIES:
                _RECENT.popitem(last=False)
        _RECENT.move_to_end(key)
        return _RECENT[key]
    path = Path(cache_dir) / f"hierarchy-{key}.npz"
    if path.exists():
        try:
            return MeshHierarchy.load(path)
        except (InputError, OSError):
            pass  # a damaged cache entry: rebuild and overwrite it
    hierarchy = _hierarchy(mesh, levels, coarsest, working_nodes)
    hierarchy.save(path)
    return hierarchy


def _hierarchy(mesh: Mesh, levels: int, coarsest: int, working_nodes: int | None) -> MeshHierarchy:
    """The hierarchy of the mesh, or of its working graph of ``working_nodes`` clusters with the map attached.

    On a working graph, nodes in no cell (a file's unused points) join the
    cluster of their nearest node that is in one.
    """
    if working_nodes is None:
        return build_hierarchy(mesh.points, mesh.edges(), levels, coarsest)
    used = np.unique(mesh.cells)
    index = np.full(mesh.n_nodes, -1, np.int64)
    index[used] = np.arange(len(used))
    points = mesh.points[used]
    edges = undirected_edges(index[mesh.edges()], len(used))
    n_comp, _ = connected_components(edge_length_graph(points, edges), directed=False)
    if n_comp != 1:
        raise MeshError(f"the mesh graph has {n_comp} connected components; a hierarchy needs a connected mesh")
    if len(used) <= working_nodes:  # the mesh's own nodes (a few unused ones apart): the graph itself
        assign, centres, working = np.arange(len(used)), points, edges
    else:
        assign, centres, working = working_clusters(points, edges, working_nodes, index[mesh.cells])
    if len(used) < mesh.n_nodes:
        unused = np.flatnonzero(index < 0)
        index[unused] = cKDTree(points).query(mesh.points[unused])[1]
    assign = assign[index]
    hierarchy = build_hierarchy(centres, working, levels, coarsest)
    return MeshHierarchy(hierarchy.graphs, hierarchy.assign, WorkingMap.of(mesh.points, assign, centres, working))
