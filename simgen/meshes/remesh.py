"""Isotropic surface remeshing (Botsch and Kobbelt 2004) and closest points on a triangle surface.

:func:`remesh` makes every edge of a triangle surface close to a target
length ``L``, so that no triangle is a needle or a cap. Each iteration

1. splits edges longer than ``4/3 L`` at their midpoint;
2. collapses edges shorter than ``4/5 L`` into one of their ends (a
   boundary node, else the sharper end: the one farther from its
   neighbours' centroid, so tips and creases stay), unless that creates an
   edge longer than ``4/3 L``, folds a triangle or breaks the manifold;
3. flips edges when that brings the valences of the four nodes around them
   closer to 6 (4 on a boundary) without making their triangles worse;
4. moves each node tangentially towards the centroid of its neighbours and
   projects it back onto the original surface; nodes near a crease of the
   original (its normal turning by more than :data:`CREASE_ANGLE`) are put
   onto the crease instead, so that sharp rims are not worn away.

A final pass flips edges to the Delaunay condition, collapses the shortest
edge of any triangle still below :data:`MIN_ANGLE`, removes interior nodes
with three neighbours (their fan folds over itself where creases meet)
and smooths again. Each
operation works on many edges at once: the edges are chosen so that no two
share a triangle (splits) or a node neighbourhood (collapses, flips), which
makes the batch equal to doing them one by one. Deterministic. Nodes on
an open boundary stay on the original boundary: they are split and merged
along it and put back onto it, never smoothed across it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import trimesh
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["MIN_ANGLE", "CREASE_ANGLE", "remesh", "edge_length_for", "closest_points", "crossing_edges"]

#: Triangles with a smaller angle (degrees) get their shortest edge collapsed in the final pass.
MIN_ANGLE = 25.0
_PASSES = 12  # batches per split, collapse or flip step
#: Edges of the original surface where its normal turns by more than this (degrees) are kept as creases.
CREASE_ANGLE = 50.0
_SNAP = 0.3  # nodes closer to a crease than this many edge lengths are put on it
_COS_FOLD = 0.5  # a collapse or flip may turn a triangle's normal by at most 60 degrees


class _Edges(NamedTuple):
    """Unique edges of a triangle list and their half-edges (half-edge ``3 t + i`` runs from corner i to i + 1)."""

    nodes: NDArray[np.int64]  # (E, 2), lower index first
    of_half: NDArray[np.int64]  # (3M,) edge of each half-edge
    halves: NDArray[np.int64]  # (E, 2) half-edges of each edge, -1 for none (boundary)


def edge_length_for(area: float, nodes: int) -> float:
    """Edge length of an equilateral triangulation of ``area`` mm^2 with ``nodes`` nodes.

    A closed triangulation has about twice as many triangles as nodes (Euler),
    each of area ``sqrt(3)/4 L^2``: ``area = 2 nodes sqrt(3)/4 L^2``.
    """
    return float(np.sqrt(2 * area / (np.sqrt(3) * nodes)))


def remesh(
    points: NDArray[np.float64],
    tris: NDArray[np.integer],
    length: float,
    iterations: int = 5,
    reference: tuple[NDArray[np.float64], NDArray[np.integer]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The surface ``(points, tris)`` remeshed with edges of about ``length`` (see the module docstring).

    Nodes are projected onto ``reference`` (``(points, tris)``; default: the
    input surface). Triangles must be consistently wound; the winding is kept.
    """
    ref_points, ref_tris = reference if reference is not None else (points, tris)
    ref_tris = np.asarray(ref_tris, dtype=np.int64)
    ref_edges = _edges(ref_tris, len(ref_points))
    ref_rim = ref_points[ref_edges.nodes[ref_edges.halves[:, 1] < 0]]  # (B, 2, 3) boundary segments
    reference = (ref_points, ref_tris, ref_rim, _creases(ref_points, ref_tris, ref_edges), length)
    P, T = np.array(points, dtype=np.float64), np.array(tris, dtype=np.int64)
    for _ in range(iterations):
        P, T = _split(P, T, 4 / 3 * length)
        P, T = _collapse(P, T, 4 / 5 * length, 4 / 3 * length)
        T = _flip(P, T, "valence")
        P = _smooth(P, T, *reference)
    T = _flip(P, T, "delaunay")
    for smooth in (True, False):  # the smoothing can put a node onto a crease next to a neighbour
        P, T = _collapse(P, T, 4 / 5 * length, 4 / 3 * length, needles=MIN_ANGLE)
        T = _drop_valence_three(P, T)
        T = _flip(P, T, "delaunay")
        if smooth:
            P = _smooth(P, T, *reference)
            T = _flip(P, T, "delaunay")
    used = np.unique(T)
    index = np.full(len(P), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return P[used], index[T]


def closest_points(
    query: NDArray[np.float64],
    points: NDArray[np.float64],
    tris: NDArray[np.integer],
    neighbours: int = 8,
    normals: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(closest, distance)``: for each query point, the nearest point on the triangles around its nearest nodes.

    Only the triangles of the ``neighbours`` nearest surface nodes are
    candidates, so the distance is an upper bound of the true one, tight for
    points near a surface of regular triangles. With ``normals`` (one per
    query point), triangles facing the other way are taken only when no
    candidate faces the same way: a point near a thin wall stays on its side.
    """
    tris = np.asarray(tris, dtype=np.int64)
    k = min(neighbours, len(points))
    _, near = cKDTree(points).query(query, k=k)
    near = near.reshape(len(query), k)
    order = np.argsort(tris.ravel(), kind="stable")
    start = np.searchsorted(tris.ravel()[order], np.arange(len(points) + 1))
    closest = np.empty_like(query, dtype=np.float64)
    distance = np.empty(len(query))
    for chunk in np.array_split(np.arange(len(query)), max(1, len(query) // 4096)):
        vertex = near[chunk].ravel()
        count = start[vertex + 1] - start[vertex]
        offset = np.repeat(start[vertex] - np.cumsum(count) + count, count) + np.arange(count.sum())
        candidate = order[offset] // 3
        owner = np.repeat(np.repeat(chunk, k), count)
        found = trimesh.triangles.closest_point(points[tris[candidate]], query[owner])
        dist = np.linalg.norm(found - query[owner], axis=1)
        rank = dist
        if normals is not None:
            facing = np.einsum("ij,ij->i", _normals(points, tris[candidate]), normals[owner]) > 0
            rank = dist + np.where(facing, 0.0, np.inf)
        best = np.lexsort((dist, rank, owner))
        first = best[np.unique(owner[best], return_index=True)[1]]
        closest[owner[first]], distance[owner[first]] = found[first], dist[first]
    return closest, distance


def crossing_edges(points: NDArray[np.float64], tris: NDArray[np.integer]) -> int:
    """How many (edge, triangle) pairs of a surface cross, the edge not touching the triangle (0: no
    self-intersection, up to coplanar overlaps)."""
    T = np.asarray(tris, dtype=np.int64)
    edges = _edges(T, len(points)).nodes
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    corner = points[T]
    centre = corner.mean(axis=1)
    reach = np.linalg.norm(corner - centre[:, None], axis=2).max(axis=1).max() + np.linalg.norm(b - a, axis=1).max() / 2
    pairs = cKDTree((a + b) / 2).query_ball_tree(cKDTree(centre), reach)
    edge = np.repeat(np.arange(len(edges)), [len(p) for p in pairs])
    tri = np.fromiter((t for p in pairs for t in p), dtype=np.int64, count=len(edge))
    apart = ~(T[tri][:, :, None] == edges[edge][:, None, :]).any(axis=(1, 2))
    edge, tri = edge[apart], tri[apart]
    # Moller-Trumbore: a + t (b - a) = p0 + u e1 + v e2 with 0 < t < 1, u, v > 0, u + v < 1
    p0, e1, e2 = corner[tri, 0], corner[tri, 1] - corner[tri, 0], corner[tri, 2] - corner[tri, 0]
    direction = b[edge] - a[edge]
    h = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-12 * np.linalg.norm(e1, axis=1) ** 2 * np.linalg.norm(direction, axis=1)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s_vec = a[edge] - p0
    u = inv * np.einsum("ij,ij->i", s_vec, h)
    q = np.cross(s_vec, e1)
    v = inv * np.einsum("ij,ij->i", direction, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    return int((ok & (u > 0) & (v > 0) & (u + v < 1) & (t > 0) & (t < 1)).sum())


def _edges(T: NDArray[np.int64], n: int) -> _Edges:
    half = T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    lo, hi = half.min(axis=1), half.max(axis=1)
    key, of_half = np.unique(lo * n + hi, return_inverse=True)
    order = np.argsort(of_half, kind="stable")
    start = np.searchsorted(of_half[order], np.arange(len(key)))
    count = np.bincount(of_half, minlength=len(key))
    halves = np.full((len(key), 2), -1, dtype=np.int64)
    halves[:, 0] = order[start]
    two = count >= 2
    halves[two, 1] = order[start[two] + 1]
    return _Edges(np.stack([key // n, key % n], axis=1), of_half.ravel(), halves)


def _corners(T: NDArray[np.int64], half: NDArray[np.int64]) -> tuple[NDArray[np.int64], ...]:
    """``(a, b, c)`` of half-edges ``a -> b`` in triangle ``(a, b, c)``."""
    t, i = half // 3, half % 3
    return T[t, i], T[t, (i + 1) % 3], T[t, (i + 2) % 3]


def _boundary_nodes(edges: _Edges, n: int) -> NDArray[np.bool_]:
    boundary = np.zeros(n, dtype=bool)
    boundary[edges.nodes[edges.halves[:, 1] < 0].ravel()] = True
    return boundary


def _split(P: NDArray[np.float64], T: NDArray[np.int64], longest: float) -> tuple[NDArray, NDArray]:
    """Edges longer than ``longest`` split at their midpoint, a batch of edges in distinct triangles at a time."""
    for _ in range(4 * _PASSES):
        edges = _edges(T, len(P))
        a, b = edges.nodes.T
        length = np.linalg.norm(P[a] - P[b], axis=1)
        long = length > longest
        if not long.any():
            break
        per_half = np.where(long[edges.of_half], length[edges.of_half], -1.0).reshape(-1, 3)
        claims = per_half.max(axis=1) > 0
        claimed_half = 3 * np.flatnonzero(claims) + per_half[claims].argmax(axis=1)
        claimed = np.bincount(edges.of_half[claimed_half], minlength=len(a))
        chosen = long & (claimed == (edges.halves >= 0).sum(axis=1))
        new_node = np.full(len(a), -1, dtype=np.int64)
        new_node[chosen] = len(P) + np.arange(chosen.sum())
        P = np.vstack([P, (P[a[chosen]] + P[b[chosen]]) / 2])
        half = np.flatnonzero(chosen[edges.of_half])
        p, q, r = _corners(T, half)
        m = new_node[edges.of_half[half]]
        T = T.copy()
        T[half // 3] = np.stack([p, m, r], axis=1)
        T = np.vstack([T, np.stack([m, q, r], axis=1)])
    return P, T


def _normals(P: NDArray[np.float64], T: NDArray[np.int64]) -> NDArray[np.float64]:
    """Triangle normals, length twice the area."""
    return np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]])


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def _min_angles(P: NDArray[np.float64], T: NDArray[np.int64]) -> NDArray[np.float64]:
    """Smallest interior angle (degrees) of each triangle."""
    p = P[T]
    side = np.stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, (i + 2) % 3], axis=1) for i in range(3)], axis=1)
    area2 = np.linalg.norm(_normals(P, T), axis=1)
    # the smallest angle is opposite the shortest side: sin = 2 A / (product of the other two)
    s = np.sort(side, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        sine = np.clip(area2 / (s[:, 1] * s[:, 2]), 0.0, 1.0)
    return np.nan_to_num(np.degrees(np.arcsin(sine)))


def _adjacency(edges: _Edges, n: int) -> sp.csr_matrix:
    a, b = edges.nodes.T
    return sp.coo_matrix((np.ones(2 * len(a), dtype=np.int8), (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()


def _independent(rank: NDArray[np.int64], members: NDArray[np.int64], n: int, ring: NDArray | None) -> NDArray:
    """Candidates (rows of ``members``, nodes) holding the lowest rank at each of their nodes' neighbourhoods.

    ``ring``: the edges whose ends also count as neighbours (one ring more); ``None``: the nodes alone.
    """
    best = np.full(n, np.iinfo(np.int64).max)
    for col in members.T:
        np.minimum.at(best, col, rank)
    if ring is not None:
        grown = best.copy()
        np.minimum.at(grown, ring[:, 0], best[ring[:, 1]])
        np.minimum.at(grown, ring[:, 1], best[ring[:, 0]])
        best = grown
    return (best[members] == rank[:, None]).all(axis=1)


def _collapse(
    P: NDArray[np.float64], T: NDArray[np.int64], shortest: float, longest: float, needles: float | None = None
) -> tuple[NDArray, NDArray]:
    """Edges shorter than ``shortest`` collapsed (or, with ``needles``, the shortest edge of each triangle whose
    smallest angle is below ``needles`` degrees), in batches of edges whose node neighbourhoods are disjoint."""
    rejected: set[tuple[int, int]] = set()
    for _ in range(4 * _PASSES):
        n = len(P)
        edges = _edges(T, n)
        a, b = edges.nodes.T
        length = np.linalg.norm(P[a] - P[b], axis=1)
        if needles is None:
            candidate = length < shortest
        else:
            bad = np.flatnonzero(_min_angles(P, T) < needles)
            per_half = length[edges.of_half].reshape(-1, 3)[bad]
            candidate = np.zeros(len(a), dtype=bool)
            candidate[edges.of_half[3 * bad + per_half.argmin(axis=1)]] = True
        boundary_node = _boundary_nodes(edges, n)
        boundary_edge = edges.halves[:, 1] < 0
        candidate &= ~(boundary_node[a] & boundary_node[b] & ~boundary_edge)
        if rejected:
            candidate &= ~np.isin(a * n + b, np.fromiter((x * n + y for x, y in rejected), dtype=np.int64))
        idx = np.flatnonzero(candidate)
        if len(idx) == 0:
            break
        keep, gone = a[idx].copy(), b[idx].copy()
        sharp = _sharpness(P, edges) + 2 * boundary_node  # boundary nodes first, then tips and creases
        swap = sharp[gone] > sharp[keep]
        keep[swap], gone[swap] = gone[swap], keep[swap].copy()
        target = P[keep]
        relax = needles is not None  # a needle may go at a sharp crease, turning its neighbours more
        ok = _collapse_ok(
            P, T, edges, idx, keep, gone, target, 2 * longest if relax else longest, 0.0 if relax else _COS_FOLD
        )
        for i in np.flatnonzero(~ok):
            rejected.add((int(a[idx[i]]), int(b[idx[i]])))
        idx, keep, gone, target = idx[ok], keep[ok], gone[ok], target[ok]
        if len(idx) == 0:
            break
        chosen = _independent(
            np.argsort(np.argsort(length[idx], kind="stable")), np.stack([keep, gone], 1), n, edges.nodes
        )
        keep, gone = keep[chosen], gone[chosen]
        P = P.copy()
        P[keep] = target[chosen]
        remap = np.arange(n)
        remap[gone] = keep
        T = remap[T]
        T = T[(T[:, 0] != T[:, 1]) & (T[:, 1] != T[:, 2]) & (T[:, 2] != T[:, 0])]
    return P, T


def _drop_valence_three(P: NDArray[np.float64], T: NDArray[np.int64]) -> NDArray[np.int64]:
    """``T`` without its interior nodes of valence 3: each node's three triangles become the one of its ring.

    Such a node carries no shape a ring triangle lacks, and where creases meet its fan can fold over
    itself. Skipped where a ring node would fall below valence 3 or the ring triangle exists already.
    """
    for _ in range(_PASSES):
        n = len(P)
        edges = _edges(T, n)
        valence = np.asarray(_adjacency(edges, n).sum(axis=1)).ravel()
        centre = np.flatnonzero((valence == 3) & ~_boundary_nodes(edges, n))
        if len(centre) == 0:
            break
        incidence = sp.csr_matrix((np.ones(T.size), (T.ravel(), np.repeat(np.arange(len(T)), 3))), shape=(n, len(T)))
        fan = incidence[centre].indices.reshape(-1, 3)  # each centre's three triangles
        first = T[fan[:, 0]]
        turn = np.argmax(first == centre[:, None], axis=1)
        a, b = first[np.arange(len(centre)), (turn + 1) % 3], first[np.arange(len(centre)), (turn + 2) % 3]
        c = (T[fan].reshape(len(centre), 9).sum(axis=1) - 3 * centre) // 2 - a - b  # each ring node is in two
        cap = np.stack([a, b, c], axis=1)
        ok = (valence[cap] > 3).all(axis=1) & ~np.isin(_triangle_keys(cap, n), _triangle_keys(T, n))
        if not ok.any():
            break
        idx = np.flatnonzero(ok)
        chosen = idx[_independent(np.arange(len(idx)), np.c_[centre[idx], cap[idx]], n, None)]
        keep = np.ones(len(T), dtype=bool)
        keep[fan[chosen].ravel()] = False
        T = np.concatenate([T[keep], cap[chosen]])
    return T


def _triangle_keys(T: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    """One integer per triangle of ``n`` nodes, the same for any order of its corners."""
    s = np.sort(T, axis=1)
    return (s[:, 0] * n + s[:, 1]) * n + s[:, 2]


def _sharpness(P: NDArray[np.float64], edges: _Edges) -> NDArray[np.float64]:
    """Distance of each node from its neighbours' centroid over their mean distance (0 flat, ~1 a tip)."""
    a, b = edges.nodes.T
    n = len(P)
    degree = np.maximum(np.bincount(np.r_[a, b], minlength=n), 1)[:, None]
    centroid = np.zeros_like(P)
    np.add.at(centroid, a, P[b])
    np.add.at(centroid, b, P[a])
    spread = np.bincount(np.r_[a, b], np.tile(np.linalg.norm(P[a] - P[b], axis=1), 2), minlength=n)
    return np.linalg.norm(centroid / degree - P, axis=1) / np.maximum(spread / degree[:, 0], 1e-300)


def _collapse_ok(
    P: NDArray[np.float64],
    T: NDArray[np.int64],
    edges: _Edges,
    idx: NDArray[np.int64],
    keep: NDArray[np.int64],
    gone: NDArray[np.int64],
    target: NDArray[np.float64],
    longest: float,
    cos_fold: float,
) -> NDArray[np.bool_]:
    """Whether collapsing each edge ``idx`` (``gone`` into ``keep`` at ``target``) keeps a valid, unfolded mesh."""
    n, k = len(P), len(idx)
    adjacency = _adjacency(edges, n)
    valence = np.asarray(adjacency.sum(axis=1)).ravel()
    common = np.asarray(adjacency[keep].multiply(adjacency[gone]).sum(axis=1)).ravel()
    sides = (edges.halves[idx] >= 0).sum(axis=1)
    ok = common == sides  # link condition: the only common neighbours are the opposite corners
    opposite = np.where(
        edges.halves[idx] >= 0, T.ravel()[(edges.halves[idx] // 3) * 3 + (edges.halves[idx] % 3 + 2) % 3], -1
    )
    ok &= ~((opposite >= 0) & (valence[np.maximum(opposite, 0)] <= 3)).any(axis=1)
    ok &= (valence[keep] + valence[gone] - 2 - sides) >= 3
    incidence = sp.coo_matrix(
        (np.ones(T.size, dtype=np.int8), (T.ravel(), np.repeat(np.arange(len(T)), 3))), shape=(n, len(T))
    ).tocsr()
    fan = (incidence[keep] + incidence[gone]).tocoo()
    owner, tri = fan.row, fan.col
    corners = T[tri]
    moved = (corners == keep[owner, None]) | (corners == gone[owner, None])
    survives = moved.sum(axis=1) == 1
    owner, tri, corners, moved = owner[survives], tri[survives], corners[survives], moved[survives]
    before = P[corners]
    after = np.where(moved[:, :, None], target[owner, None, :], before)
    old = np.cross(before[:, 1] - before[:, 0], before[:, 2] - before[:, 0])
    new = np.cross(after[:, 1] - after[:, 0], after[:, 2] - after[:, 0])
    norms = np.linalg.norm(old, axis=1) * np.linalg.norm(new, axis=1)
    folded = np.einsum("ij,ij->i", old, new) <= cos_fold * norms
    reach = np.linalg.norm(after - target[owner, None, :], axis=2).max(axis=1) > longest
    bad = np.bincount(owner[folded | reach], minlength=k) > 0
    return ok & ~bad


def _flip(P: NDArray[np.float64], T: NDArray[np.int64], mode: str) -> NDArray[np.int64]:
    """Interior edges flipped towards valence 6 (``"valence"``) or the Delaunay condition (``"delaunay"``)."""
    T = T.copy()
    for _ in range(_PASSES):
        n = len(P)
        edges = _edges(T, n)
        inner = np.flatnonzero(edges.halves[:, 1] >= 0)
        h1, h2 = edges.halves[inner].T
        a, b, c = _corners(T, h1)
        d = _corners(T, h2)[2]
        adjacency = _adjacency(edges, n)
        valence = np.asarray(adjacency.sum(axis=1)).ravel()
        old_min = np.minimum(_min_angles(P, np.stack([a, b, c], 1)), _min_angles(P, np.stack([b, a, d], 1)))
        t1, t2 = np.stack([a, d, c], 1), np.stack([d, b, c], 1)
        new_min = np.minimum(_min_angles(P, t1), _min_angles(P, t2))
        if mode == "valence":
            off = valence - np.where(_boundary_nodes(edges, n), 4, 6)  # valence minus its ideal
            quad, change = np.stack([a, b, c, d], 1), np.array([-1, -1, 1, 1])
            gain = np.abs(off[quad]).sum(axis=1) - np.abs(off[quad] + change).sum(axis=1)
            gain = gain.astype(np.float64) * (new_min >= np.minimum(old_min, MIN_ANGLE))
        else:
            gain = new_min - old_min
        n_old = _normals(P, np.stack([a, b, c], 1)) + _normals(P, np.stack([b, a, d], 1))
        n1, n2 = _normals(P, t1), _normals(P, t2)
        flat = (
            (np.einsum("ij,ij->i", _unit(n1), _unit(n2)) > _COS_FOLD)
            & (np.einsum("ij,ij->i", _unit(n1), _unit(n_old)) > _COS_FOLD)
            & (np.einsum("ij,ij->i", _unit(n2), _unit(n_old)) > _COS_FOLD)
        )
        free = np.asarray(adjacency[c, d]).ravel() == 0
        candidate = np.flatnonzero((gain > 1e-9) & flat & free & (c != d) & (valence[a] > 3) & (valence[b] > 3))
        if len(candidate) == 0:
            break
        rank = np.argsort(np.argsort(-gain[candidate], kind="stable"))
        members = np.stack([a, b, c, d], 1)[candidate]
        chosen = candidate[_independent(rank, members, n, None)]
        T[h1[chosen] // 3] = t1[chosen]
        T[h2[chosen] // 3] = t2[chosen]
    return T


def _smooth(
    P: NDArray[np.float64],
    T: NDArray[np.int64],
    ref_points: NDArray[np.float64],
    ref_tris: NDArray[np.int64],
    ref_rim: NDArray[np.float64],
    ref_creases: NDArray[np.float64],
    length: float,
) -> NDArray[np.float64]:
    """Interior nodes moved tangentially to their neighbours' centroid, then onto the reference surface;
    boundary nodes put back onto the reference boundary ``ref_rim`` and nodes within :data:`_SNAP` ``length``
    of a crease (segments ``ref_creases``) onto the crease, unsmoothed."""
    n = len(P)
    edges = _edges(T, n)
    adjacency = _adjacency(edges, n).astype(np.float64)
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    used = degree > 0
    centroid = np.zeros_like(P)
    centroid[used] = (adjacency @ P)[used] / degree[used, None]
    normal = np.zeros_like(P)
    face = _normals(P, T)
    for i in range(3):
        np.add.at(normal, T[:, i], face)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    move = centroid - P
    move -= np.einsum("ij,ij->i", move, normal)[:, None] * normal
    rim = _boundary_nodes(edges, n)
    on_crease = np.zeros(n, dtype=bool)
    if len(ref_creases):
        foot = _closest_on_segments(P, ref_creases)
        on_crease = used & ~rim & (np.linalg.norm(foot - P, axis=1) < _SNAP * length)
        snapped = np.flatnonzero(on_crease)
        close = cKDTree(foot[snapped]).query_pairs(_SNAP * length, output_type="ndarray")
        on_crease[snapped[close[:, 1]]] = False  # two nodes onto one point of a crease: the second stays off
    inner = used & ~rim & ~on_crease
    P = P.copy()
    P[inner] += move[inner]
    P[inner] = closest_points(P[inner], ref_points, ref_tris, normals=normal[inner])[0]
    if on_crease.any():
        P[on_crease] = foot[on_crease]
    if rim.any() and len(ref_rim):
        P[rim] = _closest_on_segments(P[rim], ref_rim)
    return P


def _creases(points: NDArray[np.float64], tris: NDArray[np.int64], edges: _Edges) -> NDArray[np.float64]:
    """(C, 2, 3) segments of the edges where the surface turns by more than :data:`CREASE_ANGLE`."""
    inner = np.flatnonzero(edges.halves[:, 1] >= 0)
    normal = _unit(_normals(points, tris))
    first, second = normal[edges.halves[inner, 0] // 3], normal[edges.halves[inner, 1] // 3]
    sharp = inner[np.einsum("ij,ij->i", first, second) < np.cos(np.radians(CREASE_ANGLE))]
    return points[edges.nodes[sharp]]


def _closest_on_segments(query: NDArray[np.float64], segments: NDArray[np.float64], near: int = 8) -> NDArray:
    """The nearest point of each query point on the ``near`` segments (B, 2, 3) with the closest midpoints."""
    k = min(near, len(segments))
    _, idx = cKDTree(segments.mean(axis=1)).query(query, k=k)
    a, b = segments[idx.reshape(len(query), k), 0], segments[idx.reshape(len(query), k), 1]
    ab = b - a
    t = np.einsum("ijk,ijk->ij", query[:, None] - a, ab) / np.maximum(np.einsum("ijk,ijk->ij", ab, ab), 1e-300)
    foot = a + np.clip(t, 0.0, 1.0)[:, :, None] * ab
    best = np.linalg.norm(foot - query[:, None], axis=2).argmin(axis=1)
    return foot[np.arange(len(query)), best]
