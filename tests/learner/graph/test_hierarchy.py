"""Mesh graphs and hierarchies: structure, determinism, connected clusters, pooling, caching, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

import learner.graph.hierarchy as hierarchy_module
from learner.graph import Graph, MeshHierarchy, build_hierarchy, hierarchy_for_mesh
from shared.errors import InputError, MeshError
from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh

LEVELS, COARSEST = 4, 30


@pytest.fixture(scope="module")
def mesh() -> Mesh:
    return get_mesh("lv", 500, "tetra")


@pytest.fixture(scope="module")
def hier(mesh) -> MeshHierarchy:
    return build_hierarchy(mesh.points, mesh.edges(), LEVELS, COARSEST)


def _undirected_set(edge_index: torch.Tensor) -> set[tuple[int, int]]:
    s, d = edge_index.numpy()
    return {(min(a, b), max(a, b)) for a, b in zip(s.tolist(), d.tolist())}


def _assert_same(a: MeshHierarchy, b: MeshHierarchy) -> None:
    assert a.sizes == b.sizes
    for ga, gb in zip(a.graphs, b.graphs):
        assert torch.equal(ga.edge_index, gb.edge_index)
        assert torch.equal(ga.pseudo, gb.pseudo)
        assert torch.equal(ga.positions, gb.positions)
    for xa, xb in zip(a.assign, b.assign):
        assert torch.equal(xa, xb)


def test_sizes_are_geometric(mesh, hier):
    n = mesh.n_nodes
    expected = tuple(round(n * (COARSEST / n) ** (lvl / (LEVELS - 1))) for lvl in range(LEVELS))
    assert hier.sizes == expected
    assert hier.n_levels == LEVELS and hier.sizes[-1] == COARSEST
    assert [len(a) for a in hier.assign] == list(hier.sizes[:-1])
    assert repr(hier) == f"MeshHierarchy(sizes={expected})"


def test_level_zero_is_the_mesh(mesh, hier):
    g = hier.graphs[0]
    assert g.num_nodes == mesh.n_nodes and g.num_edges == 2 * len(mesh.edges())
    assert _undirected_set(g.edge_index) == set(map(tuple, mesh.edges().tolist()))
    np.testing.assert_allclose(g.positions.numpy(), mesh.points, rtol=1e-6)


@pytest.mark.parametrize("level", range(LEVELS))
def test_graph_edges_and_pseudo_coordinates(hier, level):
    g = hier.graphs[level]
    src, dst = g.edge_index
    pairs = set(zip(src.tolist(), dst.tolist()))
    assert pairs == {(b, a) for a, b in pairs}, "every edge must exist in both directions"
    assert len(pairs) == g.num_edges and bool((src != dst).all())
    # sorted by target, then source
    key = dst * g.num_nodes + src
    assert bool((key[1:] > key[:-1]).all())
    pos = g.positions.double()
    cart = pos[src] - pos[dst]
    expected = cart / (2 * cart.abs().max()) + 0.5
    torch.testing.assert_close(g.pseudo.double(), expected, rtol=0, atol=1e-6)
    assert float(g.pseudo.min()) == 0.0 and float(g.pseudo.max()) == 1.0


@pytest.mark.parametrize("level", range(LEVELS - 1))
def test_clusters_are_connected_and_coarse_graph_follows(hier, level):
    fine, coarse, a = hier.graphs[level], hier.graphs[level + 1], hier.assign[level].numpy()
    m = coarse.num_nodes
    assert set(np.unique(a).tolist()) == set(range(m)), "no empty cluster"
    s, d = fine.edge_index.numpy()
    inside = a[s] == a[d]
    adj = coo_matrix((np.ones(inside.sum()), (s[inside], d[inside])), shape=(fine.num_nodes,) * 2)
    _, comp = connected_components(adj, directed=False)
    # a cluster is connected iff all its members share one component of the intra-cluster graph
    for c in range(m):
        assert len(np.unique(comp[a == c])) == 1, f"cluster {c} of level {level} is not connected"
    joined = {(min(x, y), max(x, y)) for x, y in zip(a[s].tolist(), a[d].tolist()) if x != y}
    assert _undirected_set(coarse.edge_index) == joined
    centroid = np.stack([np.bincount(a, fine.positions.double().numpy()[:, k]) for k in range(3)], 1)
    centroid /= np.bincount(a)[:, None]
    np.testing.assert_allclose(coarse.positions.numpy(), centroid, rtol=1e-5, atol=1e-4)
    assert connected_components(adj + adj.T, directed=False)[0] == m


def test_build_is_deterministic(mesh, hier):
    _assert_same(hier, build_hierarchy(mesh.points.copy(), mesh.edges().copy(), LEVELS, COARSEST))


def test_edge_order_and_duplicates_do_not_matter(mesh, hier):
    e = mesh.edges()
    shuffled = np.concatenate([e[::-1, ::-1], e[:50]])  # reversed pairs, reversed order, duplicates
    _assert_same(hier, build_hierarchy(mesh.points, shuffled, LEVELS, COARSEST))


def test_triangle_surface_mesh():
    m = get_mesh("lv", 300, "triangle")
    h = build_hierarchy(m.points, m.edges(), levels=3, coarsest=20)
    assert h.sizes[0] == m.n_nodes and h.sizes[-1] == 20


@pytest.mark.parametrize("level", range(LEVELS - 1))
def test_pool_and_unpool_equal_their_sparse_matrices(hier, level):
    gen = torch.Generator().manual_seed(level)
    n, m = hier.sizes[level], hier.sizes[level + 1]
    x = torch.randn(3, n, 4, generator=gen, dtype=torch.float64)
    y = torch.randn(3, m, 4, generator=gen, dtype=torch.float64)
    p = hier.pool_matrix(level, dtype=torch.float64)
    u = hier.unpool_matrix(level, dtype=torch.float64)
    assert p.shape == (m, n) and u.shape == (n, m) and p.is_sparse and u.is_sparse
    pooled, unpooled = hier.pool(x, level), hier.unpool(y, level)
    assert pooled.shape == (3, m, 4) and unpooled.shape == (3, n, 4)
    for b in range(3):
        torch.testing.assert_close(pooled[b], torch.sparse.mm(p, x[b]), rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(unpooled[b], torch.sparse.mm(u, y[b]), rtol=0, atol=0)
    dense_p = p.to_dense()
    torch.testing.assert_close(dense_p.sum(dim=1), torch.ones(m, dtype=torch.float64))
    # pooling after unpooling gives back the coarse signal (P U = I)
    torch.testing.assert_close(dense_p @ u.to_dense(), torch.eye(m, dtype=torch.float64))
    torch.testing.assert_close(hier.pool(hier.unpool(y, level), level), y)


@pytest.mark.parametrize("level", [0, LEVELS - 2])
def test_pool_and_unpool_of_column_layout_views_match(hier, level):
    """(B, N, C) views of an (N, C, B) tensor (what inference blocks return) take the row-copy path: same values."""
    gen = torch.Generator().manual_seed(level)
    x = torch.randn(5, hier.sizes[level], 3, generator=gen)
    y = torch.randn(5, hier.sizes[level + 1], 3, generator=gen)
    x_cols, y_cols = (t.permute(1, 2, 0).contiguous().permute(2, 0, 1) for t in (x, y))
    assert not x_cols.is_contiguous() and x_cols.permute(1, 2, 0).is_contiguous()
    torch.testing.assert_close(hier.pool(x_cols, level), hier.pool(x, level), rtol=0, atol=0)
    unpooled = hier.unpool(y_cols, level)
    torch.testing.assert_close(unpooled, hier.unpool(y, level), rtol=0, atol=0)
    assert unpooled.permute(1, 2, 0).is_contiguous()  # the layout carries on to the next block


def test_pool_gradient_is_the_transposed_matrix(hier):
    x = torch.randn(2, hier.sizes[0], 3, dtype=torch.float64, requires_grad=True)
    w = torch.randn(2, hier.sizes[1], 3, dtype=torch.float64)
    (hier.pool(x, 0) * w).sum().backward()
    p = hier.pool_matrix(0, dtype=torch.float64).to_dense()
    torch.testing.assert_close(x.grad, torch.einsum("mn,bmc->bnc", p, w))


def test_pool_rejects_bad_input(hier):
    with pytest.raises(InputError, match="level"):
        hier.pool(torch.zeros(1, hier.sizes[0], 1), LEVELS - 1)
    with pytest.raises(InputError, match=rf"\(B, {hier.sizes[0]}, C\)"):
        hier.pool(torch.zeros(1, hier.sizes[1], 1), 0)
    with pytest.raises(InputError, match="expects"):
        hier.unpool(torch.zeros(hier.sizes[1], 1), 0)


def test_save_load_round_trip(hier, tmp_path):
    path = tmp_path / "sub" / "h.hier"  # no .npz suffix: written exactly where asked
    hier.save(path)
    assert path.exists() and not list(path.parent.glob("*.tmp"))
    _assert_same(hier, MeshHierarchy.load(path))


def test_load_rejects_other_files(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(InputError, match="not a mesh hierarchy"):
        MeshHierarchy.load(path)
    path.write_bytes(b"garbage")
    with pytest.raises(InputError, match="not a readable"):
        MeshHierarchy.load(path)


def test_cache_hit_skips_the_build(mesh, hier, tmp_path, monkeypatch):
    first = hierarchy_for_mesh(mesh, LEVELS, COARSEST, tmp_path)
    files = sorted(tmp_path.glob("*.npz"))
    assert len(files) == 1
    _assert_same(hier, first)

    def fail(*args, **kwargs):
        raise AssertionError("build_hierarchy called on a cache hit")

    monkeypatch.setattr(hierarchy_module, "build_hierarchy", fail)
    _assert_same(hier, hierarchy_for_mesh(mesh, LEVELS, COARSEST, tmp_path))
    # other settings or another geometry are other keys
    with pytest.raises(AssertionError, match="cache hit"):
        hierarchy_for_mesh(mesh, LEVELS, COARSEST + 1, tmp_path)
    moved = Mesh(mesh.points + 1.0, mesh.cells, mesh.node_sets, name=mesh.name)
    with pytest.raises(AssertionError, match="cache hit"):
        hierarchy_for_mesh(moved, LEVELS, COARSEST, tmp_path)


def test_damaged_cache_entry_is_rebuilt(mesh, hier, tmp_path):
    hierarchy_for_mesh(mesh, LEVELS, COARSEST, tmp_path)
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(b"truncated")
    _assert_same(hier, hierarchy_for_mesh(mesh, LEVELS, COARSEST, tmp_path))
    _assert_same(hier, MeshHierarchy.load(path))


def test_no_cache_dir_builds_in_memory(tmp_path):
    m = get_mesh("lv", 200, "triangle")
    h = hierarchy_for_mesh(m, 3, 20, None)
    assert h.sizes[-1] == 20


def _grid_points(n: int) -> np.ndarray:
    return np.stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)], axis=1)


def test_path_graph_clusters_are_intervals():
    n = 60
    pts = _grid_points(n)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    h = build_hierarchy(pts, edges, levels=2, coarsest=6)
    a = h.assign[0].numpy()
    assert h.sizes == (60, 6)
    # connected clusters on a path are runs of consecutive nodes
    assert (np.diff(a) != 0).sum() == 5
    assert np.bincount(a).min() >= 3


def test_errors_name_the_problem():
    pts = _grid_points(10)
    path = np.stack([np.arange(9), np.arange(1, 10)], axis=1)
    with pytest.raises(MeshError, match="2 connected components"):
        build_hierarchy(pts, np.delete(path, 4, axis=0), levels=2, coarsest=3)
    with pytest.raises(MeshError, match="connected components"):  # isolated node
        build_hierarchy(pts, path[:-1], levels=2, coarsest=3)
    with pytest.raises(InputError, match="coarsest"):
        build_hierarchy(pts, path, levels=2, coarsest=10)
    with pytest.raises(InputError, match="coarsest"):
        build_hierarchy(pts, path, levels=2, coarsest=0)
    with pytest.raises(InputError, match="levels"):
        build_hierarchy(pts, path, levels=1, coarsest=3)
    with pytest.raises(InputError, match=r"\(E, 2\)"):
        build_hierarchy(pts, path.T, levels=2, coarsest=3)
    with pytest.raises(InputError, match="outside"):
        build_hierarchy(pts, path + 1, levels=2, coarsest=3)
    with pytest.raises(InputError, match="integer"):
        build_hierarchy(pts, path.astype(float), levels=2, coarsest=3)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        build_hierarchy(pts[:, :2], path, levels=2, coarsest=3)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(MeshError, match="non-finite"):
        build_hierarchy(bad, path, levels=2, coarsest=3)


def test_graph_validates_its_tensors():
    ei = torch.tensor([[0, 1], [1, 0]])
    pos = torch.zeros(2, 3)
    with pytest.raises(InputError, match="pseudo"):
        Graph(ei, torch.zeros(3, 3), 2, pos)
    with pytest.raises(InputError, match="outside"):
        Graph(ei + 1, torch.zeros(2, 3), 2, pos)
    with pytest.raises(InputError, match="long"):
        Graph(ei.int(), torch.zeros(2, 3), 2, pos)
    g = Graph.from_edges(np.array([[0.0, 0, 0], [2.0, 1, 0]]), np.array([[1, 0]]))
    assert repr(g) == "Graph(num_nodes=2, num_edges=2)"
    torch.testing.assert_close(g.pseudo, torch.tensor([[1.0, 0.75, 0.5], [0.0, 0.25, 0.5]]))


def test_coarsest_cluster_is_where_unpooling_brings_each_coarse_node(hier):
    """Copying each coarsest node's id down every level gives, at each mesh node, its coarsest cluster."""
    ids = torch.arange(hier.sizes[-1], dtype=torch.float64).view(1, -1, 1)
    for level in reversed(range(hier.n_levels - 1)):
        ids = hier.unpool(ids, level)
    nodes = torch.arange(hier.sizes[0])
    assert torch.equal(hier.coarsest_cluster(nodes), ids.view(-1).long())
