"""SplineConv and its B-spline basis against direct formulas (float64), gradients and edge cases."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from learner.graph import Graph
from learner.nn import SplineConv, spline_basis
from learner.nn.spline_conv import interpolation_matrix
from shared.errors import InputError


def _random_graph(n: int = 12, n_edges: int = 30, seed: int = 0, isolated: int = 1) -> Graph:
    """Random undirected graph on n nodes; the last ``isolated`` nodes have no edges."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3))
    linked = n - isolated
    e = rng.integers(0, linked, size=(n_edges, 2))
    return Graph.from_edges(pts, e)


def _direct_conv(x, graph, weight, root, bias, kernel_size=3, aggr="mean"):
    """Per-edge loop: out_i = agg_{j->i} sum_corners B * x_j @ W[k] + x_i @ root + bias (clamped knots)."""
    b, n, _ = x.shape
    out = torch.zeros(b, n, weight.shape[2], dtype=torch.float64)
    count = np.zeros(n)
    src, dst = graph.edge_index.tolist()
    pseudo = graph.pseudo.double().tolist()
    for j, i, u in zip(src, dst, pseudo):
        kernel = torch.zeros(weight.shape[1:], dtype=torch.float64)
        v = [ud * (kernel_size - 1) for ud in u]
        low = [int(np.floor(vd)) for vd in v]
        for corner in itertools.product((0, 1), repeat=3):
            value, index = 1.0, 0
            for d in range(3):
                t = v[d] - low[d]
                value *= t if corner[d] else 1.0 - t
                index += min(low[d] + corner[d], kernel_size - 1) * kernel_size**d
            kernel += value * weight[index].double()
        out[:, i] += x[:, j].double() @ kernel
        count[i] += 1
    if aggr == "mean":
        out /= torch.from_numpy(np.maximum(count, 1)).view(1, n, 1)
    if root is not None:
        out += x.double() @ root.double()
    if bias is not None:
        out += bias.double()
    return out


def _randomise(conv: SplineConv, seed: int = 1) -> None:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in conv.parameters():
            p.copy_(torch.randn(p.shape, generator=gen, dtype=p.dtype))


def test_basis_at_a_known_point():
    basis, index = spline_basis(torch.tensor([[0.25, 0.5, 1.0]], dtype=torch.float64))
    # v = (0.5, 1, 2): only the corners with k1 = k2 = 0 carry weight, 0.5 each
    expected_basis = torch.zeros(1, 8, dtype=torch.float64)
    expected_basis[0, 0] = expected_basis[0, 1] = 0.5
    torch.testing.assert_close(basis, expected_basis)
    assert index[0, 0] == 0 + 1 * 3 + 2 * 9 and index[0, 1] == 1 + 1 * 3 + 2 * 9
    assert index.dtype == torch.long and int(index.min()) >= 0 and int(index.max()) < 27


def test_basis_is_a_partition_of_unity():
    u = torch.rand(500, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    u[:6] = torch.tensor([[0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5], [1, 0, 0.5], [0, 1, 1], [0.999999, 1e-9, 1]])
    basis, index = spline_basis(u, kernel_size=5)
    assert basis.shape == (500, 8) and index.shape == (500, 8)
    assert bool((basis >= 0).all())
    torch.testing.assert_close(basis.sum(1), torch.ones(500, dtype=torch.float64))
    assert int(index.max()) < 125


@pytest.mark.parametrize("kernel_size", [2, 3, 4])
def test_kernels_are_trilinear_interpolation_of_the_knot_weights(kernel_size):
    """W(u) = sum_s B_s W[k_s] is the trilinear interpolant of the knot grid (scipy reference)."""
    graph = _random_graph(20, 60, seed=kernel_size)
    weight = torch.randn(kernel_size**3, 2, 3, dtype=torch.float64)
    kernels = interpolation_matrix(graph, kernel_size, torch.float64) @ weight.view(kernel_size**3, -1)
    # weight index = i0 + K i1 + K^2 i2, so the grid axes are (i2, i1, i0) before transposing
    grid = weight.view(kernel_size, kernel_size, kernel_size, 6).permute(2, 1, 0, 3).numpy()
    knots = np.linspace(0, 1, kernel_size)
    reference = RegularGridInterpolator((knots, knots, knots), grid)(graph.pseudo.double().numpy())
    np.testing.assert_allclose(kernels.numpy(), reference, rtol=1e-5, atol=1e-5)  # pseudo is float32


METHODS = ("edges", "sparse")


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    "aggr, root_weight, bias, cin, cout",
    [("mean", True, True, 3, 4), ("add", False, True, 1, 2), ("mean", True, False, 2, 1)],
)
def test_matches_direct_per_edge_formula(aggr, root_weight, bias, cin, cout, method):
    graph = _random_graph(12, 30, seed=2, isolated=2)
    conv = SplineConv(cin, cout, aggr=aggr, root_weight=root_weight, bias=bias, method=method).double()
    _randomise(conv)
    x = torch.randn(3, 12, cin, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    out = conv(x, graph)
    ref = _direct_conv(x, graph, conv.weight, conv.root, conv.bias, aggr=aggr)
    assert out.shape == (3, 12, cout) and out.is_contiguous()
    torch.testing.assert_close(out, ref, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("method", METHODS)
def test_float32_matches_float64_formula(method):
    graph = _random_graph(15, 40, seed=4)
    conv = SplineConv(4, 5, method=method)
    _randomise(conv)
    x = torch.randn(2, 15, 4)
    ref = _direct_conv(x, graph, conv.weight, conv.root, conv.bias)
    torch.testing.assert_close(conv(x, graph).double(), ref, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("method", METHODS)
def test_isolated_nodes_get_root_term_and_bias_only(method):
    graph = _random_graph(10, 20, seed=5, isolated=3)
    conv = SplineConv(2, 3, method=method).double()
    _randomise(conv)
    x = torch.randn(2, 10, 2, dtype=torch.float64)
    out = conv(x, graph)
    torch.testing.assert_close(out[:, 7:], x[:, 7:] @ conv.root + conv.bias)


def test_constant_kernel_is_mean_aggregation():
    graph = _random_graph(10, 25, seed=6)
    conv = SplineConv(2, 2, root_weight=False, bias=False).double()
    m = torch.tensor([[1.0, 2.0], [-1.0, 0.5]], dtype=torch.float64)
    with torch.no_grad():
        conv.weight.copy_(m.expand(27, 2, 2))
    x = torch.randn(1, 10, 2, dtype=torch.float64)
    src, dst = graph.edge_index
    mean = torch.zeros(10, 2, dtype=torch.float64).index_add_(0, dst, x[0, src])
    mean /= torch.bincount(dst, minlength=10).clamp(min=1).unsqueeze(1)
    torch.testing.assert_close(conv(x, graph)[0], mean @ m)


def test_batch_items_are_independent():
    graph = _random_graph(12, 30, seed=7)
    conv = SplineConv(3, 4)
    x = torch.randn(5, 12, 3)
    out = conv(x, graph)
    for b in range(5):
        torch.testing.assert_close(out[b : b + 1], conv(x[b : b + 1], graph))


@pytest.mark.parametrize("method", METHODS)
def test_gradcheck(method):
    graph = _random_graph(6, 9, seed=8)
    conv = SplineConv(2, 3, method=method).double()
    _randomise(conv)
    x = torch.randn(2, 6, 2, dtype=torch.float64, requires_grad=True)

    def f(x, weight, root, bias):
        conv.weight, conv.root, conv.bias = weight, root, bias
        return conv(x, graph)

    params = [torch.nn.Parameter(p.detach().clone()) for p in (conv.weight, conv.root, conv.bias)]
    assert torch.autograd.gradcheck(f, (x, *params), eps=1e-6, atol=1e-7)


def test_interpolation_matrix_is_cached_per_graph_and_dtype():
    graph = _random_graph(8, 12, seed=9)
    a = interpolation_matrix(graph, 3, torch.float32)
    assert interpolation_matrix(graph, 3, torch.float32) is a
    b = interpolation_matrix(graph, 3, torch.float64)
    assert b.dtype == torch.float64 and b is not a
    assert interpolation_matrix(graph, 4, torch.float32).shape == (graph.num_edges, 64)
    torch.testing.assert_close(a.sum(1), torch.ones(graph.num_edges))


@pytest.mark.parametrize("method", METHODS)
def test_graph_without_edges(method):
    graph = Graph.from_edges(np.random.default_rng(0).normal(size=(4, 3)), np.zeros((0, 2), dtype=int))
    conv = SplineConv(2, 3, method=method)
    x = torch.randn(2, 4, 2)
    torch.testing.assert_close(conv(x, graph), x @ conv.root + conv.bias)


def test_methods_agree_in_values_and_gradients_with_repeated_edges():
    base = _random_graph(20, 60, seed=10, isolated=2)
    repeated = base.edge_index[:, :5]
    graph = Graph(
        torch.cat([base.edge_index, repeated], 1),
        torch.cat([base.pseudo, base.pseudo[:5]]),
        base.num_nodes,
        base.positions,
    )
    x = torch.randn(4, 20, 3, dtype=torch.float64, requires_grad=True)
    results = []
    for method in METHODS:
        conv = SplineConv(3, 2, method=method).double()
        _randomise(conv)
        out = conv(x, graph)
        grads = torch.autograd.grad(out.sin().sum(), [x, *conv.parameters()])
        results.append((out, grads))
    (a, ga), (b, gb) = results
    torch.testing.assert_close(a, b)
    for u, v in zip(ga, gb):
        torch.testing.assert_close(u, v)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("cin, cout, batch", [(3, 3, 4), (3, 3, 40), (3, 2, 40)])  # CSR, block-CSR, CSR
def test_inference_operator_matches_the_training_path(method, cin, cout, batch):
    graph = _random_graph(20, 60, seed=11, isolated=2)
    conv = SplineConv(cin, cout, method=method).double()
    _randomise(conv)
    x = torch.randn(batch, 20, cin, dtype=torch.float64)
    expected = _direct_conv(x, graph, conv.weight, conv.root, conv.bias)
    with torch.no_grad():
        out = conv(x, graph)
        cols = conv.columns(x.permute(1, 2, 0).reshape(20 * cin, batch), graph)
        layout = conv.operator(graph, batch).layout
    torch.testing.assert_close(out, expected)
    torch.testing.assert_close(cols.view(20, cout, batch).permute(2, 0, 1), expected)
    assert layout == (torch.sparse_bsr if cin == cout and batch >= 32 else torch.sparse_csr)


def test_inference_caches_follow_the_weights():
    graph = _random_graph(12, 30, seed=12)
    conv = SplineConv(2, 2)
    x = torch.randn(3, 12, 2)
    opt = torch.optim.SGD(conv.parameters(), lr=0.5)
    for _ in range(2):
        with torch.no_grad():
            before = conv(x, graph)
            assert conv.operator(graph) is conv.operator(graph)  # kept while the weights stand still
        conv(x, graph).square().sum().backward()  # with autograd: no cache, fresh kernels
        opt.step()
        opt.zero_grad()
        with torch.no_grad():
            after = conv(x, graph)
        expected = _direct_conv(x, graph, conv.weight, conv.root, conv.bias).float()
        torch.testing.assert_close(after, expected, rtol=1e-4, atol=1e-4)
        assert not torch.allclose(after, before)
    with torch.no_grad():
        conv.root.mul_(2.0)  # the root block is part of the operator too
        expected = _direct_conv(x, graph, conv.weight, conv.root, conv.bias).float()
        torch.testing.assert_close(conv(x, graph), expected, rtol=1e-4, atol=1e-4)
    with pytest.raises(RuntimeError, match="inference"):
        conv.operator(graph)


def test_auto_method_takes_the_sparse_product_for_small_kernels():
    assert SplineConv(8, 8).method == "sparse" and SplineConv(2, 8).method == "sparse"
    assert SplineConv(16, 16).method == "sparse"  # training: no per-edge intermediates to keep for backward
    assert SplineConv(32, 16).method == "edges" and SplineConv(64, 32).method == "edges"
    assert SplineConv(8, 16).inference_method == "sparse" and SplineConv(16, 16).inference_method == "edges"
    assert SplineConv(16, 16, method="sparse").inference_method == "sparse"  # an explicit method holds for both


def test_inference_runs_the_inference_method(monkeypatch):
    graph = _random_graph(20, 60, seed=5)
    conv = SplineConv(16, 16)
    x = torch.randn(3, 20, 16)
    calls = []
    monkeypatch.setattr(conv, "_edges", lambda *a: calls.append("edges") or torch.zeros(3, 20, 16))
    monkeypatch.setattr(conv, "_sparse", lambda *a: calls.append("sparse") or torch.zeros(3, 20, 16))
    conv(x, graph)
    with torch.no_grad():
        conv(x, graph)
    assert calls == ["sparse", "edges"]


def test_block_pattern_has_32_bit_indices():
    """MKL / cuSPARSE multiply with 32-bit indices; int64 ones would be converted on every product."""
    graph = _random_graph(20, 60, seed=3)
    conv = SplineConv(4, 4)
    with torch.no_grad():
        op = conv.operator(graph)
    assert op.crow_indices().dtype == op.col_indices().dtype == torch.int32


def test_repr_and_parameter_shapes():
    conv = SplineConv(3, 5, kernel_size=4, aggr="add", bias=False)
    assert repr(conv) == (
        "SplineConv(3, 5, dim=3, kernel_size=4, degree=1, aggr='add', root_weight=True, bias=False, method='sparse')"
    )
    assert conv.weight.shape == (64, 3, 5) and conv.root.shape == (3, 5) and conv.bias is None
    assert sum(p.numel() for p in conv.parameters()) == 64 * 15 + 15


def test_bad_input_is_refused():
    with pytest.raises(InputError, match="degree"):
        SplineConv(2, 2, degree=2)
    with pytest.raises(InputError, match="degree"):
        spline_basis(torch.rand(3, 3), degree=3)
    with pytest.raises(InputError, match="aggr"):
        SplineConv(2, 2, aggr="max")
    with pytest.raises(InputError, match="method"):
        SplineConv(2, 2, method="dense")
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        spline_basis(torch.tensor([[0.5, 1.2, 0.0]]))
    with pytest.raises(InputError, match=r"\(E, D\)"):
        spline_basis(torch.rand(3))
    graph = _random_graph(6, 9)
    conv = SplineConv(2, 3)
    with pytest.raises(InputError, match=r"\(B, 6, 2\)"):
        conv(torch.zeros(1, 5, 2), graph)
    with pytest.raises(InputError, match=r"\(B, 6, 2\)"):
        conv(torch.zeros(1, 6, 3), graph)
    with pytest.raises(InputError, match=r"\(B, 6, 2\)"):
        conv(torch.zeros(6, 2), graph)
    with pytest.raises(InputError, match="dims"):
        SplineConv(2, 3, dim=2)(torch.zeros(1, 6, 2), graph)
