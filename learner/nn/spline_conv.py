r"""Continuous B-spline kernel graph convolution (SplineCNN, Fey et al. 2018), degree 1.

.. math::

    x'_i = \frac{1}{|\mathcal N(i)|} \sum_{j \to i} x_j\, W(u_{ji})
           + x_i W_{\mathrm{root}} + b,
    \qquad W(u) = \sum_{s} B_s(u)\, W_{k_s(u)}

with :math:`u_{ji} \in [0,1]^D` the edge pseudo-coordinates and
:math:`W(u)` the multilinear interpolation of ``kernel_size**D`` weight
matrices on a regular grid of knots (open B-splines of degree 1).

Two evaluations of the same map:

* ``"edges"``: gather :math:`x_j` per edge, one small matmul per edge
  (``bmm``), scatter-add to :math:`i`. Its ``(E, B, C)`` intermediates make it
  memory-bound when channels are few and the batch is large.
* ``"sparse"``: the layer as one block-sparse matrix :math:`L` of shape
  ``(N out, N in)`` (block ``(i, j)`` = :math:`W(u_{ji})/|\mathcal N(i)|`, diagonal
  blocks :math:`W_{root}`) times the features laid out ``(N in, B)``: a CSR
  product with no per-edge intermediates (9x faster forward on one thread for
  8 channels x 55 frames on a 2k-node mesh). The backward pass multiplies by :math:`L^T`
  for the input gradient and samples :math:`g x^T` on :math:`L`'s pattern
  (SDDMM) for the kernels. At inference :meth:`SplineConv.operator` keeps
  :math:`L` per graph until the weights change, and :meth:`SplineConv.columns`
  applies it to features already in the ``(N in, B)`` layout.

``"auto"`` (the default) takes ``"sparse"`` when ``in * out <= 256`` in training
(forward + backward) and when ``in * out <= 128`` at inference, where the
per-edge kernels are kept and ``bmm`` wins from 16 x 16 channels on (crossovers
measured on one thread; ``bench/surrogate.py`` compares both on whole models).
"""

from __future__ import annotations

import math
import warnings
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import Graph
from shared.errors import InputError

__all__ = ["spline_basis", "interpolation_matrix", "SplineConv"]

_AGGREGATIONS = ("mean", "add")
_METHODS = ("auto", "edges", "sparse")
_SPARSE_MAX_KERNEL = {"train": 256, "inference": 128}  # "auto": the block-sparse product up to in * out
_BSR_MIN_BATCH = 32  # inference on square blocks: block-CSR from this many columns on

# interpolation matrices per graph: the basis costs more than the kernel matmul, and graphs are reused
_INTERPOLATION_CACHE: weakref.WeakKeyDictionary[Graph, dict[tuple, Tensor]] = weakref.WeakKeyDictionary()
_PATTERN_CACHE: weakref.WeakKeyDictionary[Graph, dict[tuple, _BlockPattern]] = weakref.WeakKeyDictionary()


def spline_basis(pseudo: Tensor, kernel_size: int = 3, degree: int = 1) -> tuple[Tensor, Tensor]:
    r"""Open degree-1 B-spline basis products and weight indices of each edge.

    Per dimension :math:`v_d = u_d (K - 1)`, :math:`f_d = \lfloor v_d \rfloor`,
    :math:`t_d = v_d - f_d`; corner ``s`` (bit ``d`` of ``s`` is
    :math:`k_d \in \{0, 1\}`) has basis :math:`\prod_d (k_d\, t_d + (1-k_d)(1-t_d))`
    and weight index :math:`\sum_d ((f_d + k_d) \bmod K)\, K^d`
    (``torch_spline_conv`` semantics; at :math:`u_d = 1` the wrapped corner has basis 0).

    Parameters
    ----------
    pseudo : (E, D) pseudo-coordinates in [0, 1].
    kernel_size : knots per dimension ``K`` (>= 2).
    degree : spline degree; only 1 is supported.

    Returns
    -------
    basis : (E, 2**D) float, each row sums to 1.
    weight_index : (E, 2**D) long in ``[0, K**D)``.
    """
    if degree != 1:
        raise InputError(f"only degree-1 (linear) B-splines are supported, got degree={degree}")
    if kernel_size < 2:
        raise InputError(f"kernel_size must be >= 2 for open degree-1 splines, got {kernel_size}")
    if pseudo.dim() != 2:
        raise InputError(f"pseudo must have shape (E, D), got {tuple(pseudo.shape)}")
    if not pseudo.is_floating_point():
        raise InputError(f"pseudo must be floating point, got {pseudo.dtype}")
    if pseudo.numel() and (bool((pseudo < 0).any()) or bool((pseudo > 1).any())):
        raise InputError("pseudo-coordinates must lie in [0, 1] (use normalised Cartesian edge attributes)")
    dims = pseudo.shape[1]
    v = pseudo * (kernel_size - degree)
    low = v.floor()
    frac = (v - low).unsqueeze(1)  # (E, 1, D)
    corners = torch.arange(2**dims, device=pseudo.device)
    bits = (corners.unsqueeze(1) >> torch.arange(dims, device=pseudo.device)) & 1  # (S, D)
    basis = torch.where(bits.bool(), frac, 1 - frac).prod(dim=-1)
    stride = kernel_size ** torch.arange(dims, device=pseudo.device)
    weight_index = (((low.long().unsqueeze(1) + bits) % kernel_size) * stride).sum(dim=-1)
    return basis, weight_index


def interpolation_matrix(graph: Graph, kernel_size: int = 3, dtype: torch.dtype = torch.float32) -> Tensor:
    """Dense ``(E, K**D)`` matrix ``M`` with :math:`W(u_e) = \\sum_k M_{ek} W_k` (degree-1 splines).

    Cached per graph, kernel size, dtype and device (the graph's pseudo-coordinates
    are taken as fixed; a ``pseudo`` that requires grad is never cached).
    """
    pseudo = graph.pseudo
    key = (kernel_size, dtype, pseudo.device)
    cache = None if pseudo.requires_grad else _INTERPOLATION_CACHE.setdefault(graph, {})
    if cache is not None and key in cache:
        return cache[key]
    basis, index = spline_basis(pseudo.to(dtype), kernel_size, 1)
    dims = pseudo.shape[1]
    interp = basis.new_zeros(graph.num_edges, kernel_size**dims).scatter_add_(1, index, basis)
    if cache is not None:
        cache[key] = interp
    return interp


# the CSR product warns once per process that sparse CSR support is "beta"; it is tested here
warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta", category=UserWarning)


@dataclass(frozen=True)
class _BlockPairs:
    """A layer's matrix on one graph as block-CSR: one ``(out, in)`` block per distinct (target, source)
    pair of its edges (and self-loops, with a root weight), whatever the channel counts; ``inverse`` maps
    each stacked block to its pair, ``degree`` counts each node's incoming edges (at least 1)."""

    nodes: int
    crow: Tensor
    col: Tensor
    inverse: Tensor
    degree: Tensor


def _block_pairs(graph: Graph, root: bool) -> _BlockPairs:
    """The (cached) block-CSR structure of a layer on ``graph`` (with self-loops for a ``root`` weight)."""
    cache = _PATTERN_CACHE.setdefault(graph, {})
    if ("pairs", root) in cache:
        return cache["pairs", root]
    n = graph.num_nodes
    src, dst = graph.edge_index[0], graph.edge_index[1]
    degree = torch.bincount(dst, minlength=n).clamp_(min=1)
    if root:
        loop = torch.arange(n, device=dst.device)
        src, dst = torch.cat([src, loop]), torch.cat([dst, loop])
    keys, inverse = torch.unique(dst * n + src, sorted=True, return_inverse=True)
    index = torch.int32 if n < 2**31 else torch.int64
    pairs = _BlockPairs(n, _row_pointers(keys // n, n).to(index), (keys % n).to(index), inverse, degree)
    cache["pairs", root] = pairs
    return pairs


@dataclass(frozen=True)
class _BlockPattern:
    """Structure of a layer's block-sparse matrix on one graph, for given channel counts, as scalar CSR.

    The blocks are the graph's edges, then one self-loop per node when the
    layer has a root weight (:class:`_BlockPairs`); ``inverse`` maps each
    scalar of the stacked ``(M, in, out)`` blocks to its CSR value (blocks of
    repeated edges add up); ``degree`` counts each node's incoming edges (at
    least 1) for mean aggregation. :meth:`transposed` gives the transpose's
    structure, which only a backward pass needs.
    """

    nodes: int
    cin: int
    cout: int
    degree: Tensor
    inverse: Tensor
    crow: Tensor
    col: Tensor
    _transposed: dict = field(default_factory=dict, repr=False, compare=False)

    def transposed(self) -> tuple[Tensor, Tensor, Tensor]:
        """``(crow_t, col_t, order_t)``: the transpose's CSR structure, ``order_t`` taking this matrix's values
        to the transpose's (computed on the first call)."""
        if not self._transposed:
            row = torch.repeat_interleave(
                torch.arange(self.nodes * self.cout, device=self.col.device), self.crow.diff().long()
            )
            col = self.col.long()
            order_t = torch.argsort(col * (self.nodes * self.cout) + row)
            rows_t = _row_pointers(col, self.nodes * self.cin)
            self._transposed.update(t=(rows_t.to(self.crow.dtype), row[order_t].to(self.crow.dtype), order_t))
        return self._transposed["t"]


def _block_pattern(graph: Graph, cin: int, cout: int, root: bool) -> _BlockPattern:
    """The (cached) scalar CSR structure of a layer with ``cin -> cout`` channels on ``graph``.

    Built from its block pairs (:func:`_block_pairs`) by arithmetic: the ``k``
    blocks of target node ``d`` (sorted by source) fill its ``cout`` rows, row
    ``(d, o)`` holding ``k cin`` entries, block ``r``'s at ``r cin + c``.
    """
    key = (cin, cout, root)
    cache = _PATTERN_CACHE.setdefault(graph, {})
    if key in cache:
        return cache[key]
    pairs = _block_pairs(graph, root)
    n, device = graph.num_nodes, graph.edge_index.device
    start, count = pairs.crow[:-1].long(), pairs.crow.diff().long()  # per target node: its first pair, its pairs
    dst = torch.repeat_interleave(torch.arange(n, device=device), count)  # target of each pair
    rank = torch.arange(len(dst), device=device) - start[dst]
    c, o = torch.arange(cin, device=device).view(1, -1, 1), torch.arange(cout, device=device).view(1, 1, -1)
    position = (start[dst] * cin * cout).view(-1, 1, 1) + o * (count[dst] * cin).view(-1, 1, 1)
    position = position + (rank * cin).view(-1, 1, 1) + c  # (pairs, cin, cout): where each scalar goes
    col = torch.empty(len(dst) * cin * cout, dtype=torch.long, device=device)
    col[position.reshape(-1)] = (pairs.col.long().view(-1, 1, 1) * cin + c).expand(-1, cin, cout).reshape(-1)
    rows = torch.arange(n * cout, device=device)
    crow = torch.cat(
        [
            start.repeat_interleave(cout) * cin * cout + (rows % cout) * count.repeat_interleave(cout) * cin,
            torch.tensor([len(col)], device=device),
        ]
    )
    # MKL and cuSPARSE take 32-bit indices: int64 ones are converted on every product
    index = torch.int32 if len(col) < 2**31 and n * max(cin, cout) < 2**31 else torch.int64
    inverse = position[pairs.inverse].reshape(-1)
    pattern = _BlockPattern(n, cin, cout, pairs.degree, inverse, crow.to(index), col.to(index))
    cache[key] = pattern
    return pattern


def _row_pointers(rows: Tensor, n_rows: int) -> Tensor:
    """CSR row pointers of sorted row indices."""
    return torch.cat([rows.new_zeros(1), torch.bincount(rows, minlength=n_rows).cumsum(0)])


def _assemble(blocks: Tensor, pattern: _BlockPattern) -> Tensor:
    """The CSR matrix ``(N out, N in)`` of per-entry blocks ``(M, in, out)`` (repeated entries add up)."""
    values = blocks.new_zeros(len(pattern.col)).index_add_(0, pattern.inverse, blocks.reshape(-1))
    shape = (pattern.nodes * pattern.cout, pattern.nodes * pattern.cin)
    return torch.sparse_csr_tensor(pattern.crow, pattern.col, values, shape, check_invariants=False)


def _assemble_blocks(blocks: Tensor, pairs: _BlockPairs, cin: int, cout: int) -> Tensor:
    """The block-CSR matrix ``(N out, N in)`` of per-entry blocks ``(M, in, out)``, built from the blocks
    directly (converting the CSR matrix took over a second per layer on a 1,000-node mesh)."""
    values = blocks.new_zeros(len(pairs.col), cin, cout).index_add_(0, pairs.inverse, blocks)
    shape = (pairs.nodes * cout, pairs.nodes * cin)
    return torch.sparse_bsr_tensor(
        pairs.crow, pairs.col, values.transpose(1, 2).contiguous(), shape, check_invariants=False
    )


class _BlockSparseProduct(torch.autograd.Function):
    """``y = L x`` for ``x`` laid out ``(N in, B)`` and ``L`` assembled from per-entry blocks ``(M, in, out)``.

    In float32 or wider (the sparse kernels have no half-precision CPU version): under autocast the
    inputs are cast up and the gradients back to the inputs' dtypes.
    """

    @staticmethod
    def forward(ctx, x: Tensor, blocks: Tensor, pattern: _BlockPattern) -> Tensor:  # type: ignore[override]
        ctx.dtypes = (x.dtype, blocks.dtype)
        dtype = torch.promote_types(torch.promote_types(x.dtype, blocks.dtype), torch.float32)
        with torch.autocast(x.device.type, enabled=False):
            x = x.to(dtype)
            matrix = _assemble(blocks.to(dtype), pattern)
            y = matrix @ x
        values = matrix.values()
        ctx.save_for_backward(x, values)
        ctx.pattern = pattern
        return y

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_y: Tensor) -> tuple[Tensor | None, Tensor | None, None]:  # type: ignore[override]
        x, values = ctx.saved_tensors
        p: _BlockPattern = ctx.pattern
        grad_y = grad_y.to(values.dtype).contiguous()
        grad_x = grad_blocks = None
        if ctx.needs_input_grad[0]:
            shape = (p.nodes * p.cin, p.nodes * p.cout)
            crow_t, col_t, order_t = p.transposed()
            transpose = torch.sparse_csr_tensor(crow_t, col_t, values[order_t], shape, check_invariants=False)
            grad_x = (transpose @ grad_y).to(ctx.dtypes[0])
        if ctx.needs_input_grad[1]:
            # d loss / d L is (grad_y x^T) sampled on L's pattern (SDDMM); every block sharing a value gets it
            shape = (p.nodes * p.cout, p.nodes * p.cin)
            pattern = torch.sparse_csr_tensor(p.crow, p.col, values, shape, check_invariants=False)
            grad_values = torch.sparse.sampled_addmm(pattern, grad_y, x.t(), beta=0.0).values()
            grad_blocks = grad_values[p.inverse].view(-1, p.cin, p.cout).to(ctx.dtypes[1])
        return grad_x, grad_blocks, None


class SplineConv(nn.Module):
    """Spline-based graph convolution on batched node features ``(B, N, C)``.

    Parameters
    ----------
    in_channels, out_channels : feature sizes.
    dim : pseudo-coordinate dimension ``D``.
    kernel_size : knots per dimension ``K``; the layer holds ``K**D`` weight matrices.
    degree : B-spline degree (only 1).
    aggr : ``"mean"`` (over incoming edges) or ``"add"``.
    root_weight : add the node's own term :math:`x_i W_{root}`.
    bias : add a learnable bias.
    method : ``"auto"``, ``"edges"`` or ``"sparse"`` (module docstring); every
        method computes the same map with the same parameters. ``"auto"`` may
        choose differently for training and inference (:attr:`method`,
        :attr:`inference_method`).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        dim: int = 3,
        kernel_size: int = 3,
        degree: int = 1,
        aggr: str = "mean",
        root_weight: bool = True,
        bias: bool = True,
        method: str = "auto",
    ) -> None:
        super().__init__()
        if degree != 1:
            raise InputError(f"SplineConv supports degree=1 only, got degree={degree}")
        if aggr not in _AGGREGATIONS:
            raise InputError(f"aggr must be one of {_AGGREGATIONS}, got {aggr!r}")
        if method not in _METHODS:
            raise InputError(f"method must be one of {_METHODS}, got {method!r}")
        if min(in_channels, out_channels, dim) < 1 or kernel_size < 2:
            raise InputError(
                f"need in/out channels >= 1, dim >= 1, kernel_size >= 2; got {in_channels}, {out_channels}, "
                f"{dim}, {kernel_size}"
            )
        self.in_channels, self.out_channels = in_channels, out_channels
        self.dim, self.kernel_size, self.degree, self.aggr = dim, kernel_size, degree, aggr
        self.method = self.auto_method(in_channels, out_channels) if method == "auto" else method
        self.inference_method = self.auto_method(in_channels, out_channels, True) if method == "auto" else method
        self._inference_cache: weakref.WeakKeyDictionary[Graph, dict[str, tuple]] = weakref.WeakKeyDictionary()
        self.weight = nn.Parameter(torch.empty(kernel_size**dim, in_channels, out_channels))
        self.root = nn.Parameter(torch.empty(in_channels, out_channels)) if root_weight else None
        self.bias = nn.Parameter(torch.empty(out_channels)) if bias else None
        self.reset_parameters()

    @staticmethod
    def auto_method(in_channels: int, out_channels: int, inference: bool = False) -> str:
        """The method ``"auto"`` picks: the block-sparse product for small kernels (measured crossovers)."""
        limit = _SPARSE_MAX_KERNEL["inference" if inference else "train"]
        return "sparse" if in_channels * out_channels <= limit else "edges"

    def active_method(self) -> str:
        """The method of the next call: :attr:`method` with autograd on, :attr:`inference_method` without."""
        return self.method if torch.is_grad_enabled() else self.inference_method

    def reset_parameters(self) -> None:
        """PyG initialisation: kernels U(+-1/sqrt(K^D in)), root U(+-1/sqrt(in)), bias 0."""
        bound = 1.0 / math.sqrt(self.weight.shape[0] * self.in_channels)
        nn.init.uniform_(self.weight, -bound, bound)
        if self.root is not None:
            bound = 1.0 / math.sqrt(self.in_channels)
            nn.init.uniform_(self.root, -bound, bound)
        if self.bias is not None:
            nn.init.zeros_(self.bias)

    def edge_kernels(self, graph: Graph) -> Tensor:
        """Interpolated kernel of every edge, ``(E, in, out)``.

        Without autograd (inference) the kernels are kept per graph until the
        weights change (see :meth:`_cached`).
        """
        if torch.is_grad_enabled():
            return self._interpolate_kernels(graph)
        return self._cached(graph, "kernels", lambda: self._interpolate_kernels(graph))

    def operator(self, graph: Graph, batch: int = 1) -> Tensor:
        """The layer without its bias as one sparse matrix ``(N out, N in)`` on features laid out ``(N in, B)``.

        Inference only (assembled once per graph and kept until the weights
        change); training goes through :class:`_BlockSparseProduct`. CSR, or
        block-CSR for square blocks on the CPU when ``batch`` (the columns it
        will multiply) is >= ``_BSR_MIN_BATCH``: 1.1-1.3x faster there, up to 2x
        slower for 5-19 columns (measured; MKL takes square blocks only).
        """
        if torch.is_grad_enabled():
            raise RuntimeError("SplineConv.operator is for inference; run it under torch.no_grad()")

        cin, cout, root = self.in_channels, self.out_channels, self.root is not None
        if cin == cout and graph.edge_index.device.type == "cpu" and batch >= _BSR_MIN_BATCH:
            pairs = _block_pairs(graph, root)

            def block_csr() -> Tensor:
                return _assemble_blocks(self._blocks(graph, self.edge_kernels(graph), pairs.degree), pairs, cin, cout)

            return self._cached(graph, "operator-bsr", block_csr)
        pattern = _block_pattern(graph, cin, cout, root)

        def csr() -> Tensor:
            return _assemble(self._blocks(graph, self.edge_kernels(graph), pattern.degree), pattern)

        return self._cached(graph, "operator", csr)

    def columns(self, cols: Tensor, graph: Graph) -> Tensor:
        """Inference on features laid out ``(N in, B)`` (node-major, batch last): ``(N out, B)``.

        The layout of the block-sparse product, so layers applied in a row
        (a residual block) skip the transposes of :meth:`forward`.
        """
        y = self.operator(graph, cols.shape[1]) @ cols
        if self.bias is not None:
            y.view(graph.num_nodes, self.out_channels, -1).add_(self.bias.view(1, -1, 1))
        return y

    def _cached(self, graph: Graph, name: str, build: Callable[[], Tensor]) -> Tensor:
        """``build()``, kept per graph and ``name`` until a weight changes.

        The key is each weight's version counter (it moves on every in-place
        update, e.g. an optimiser step) and storage, and the inference mode.
        """
        key = tuple((p._version, p.data_ptr()) for p in (self.weight, self.root) if p is not None)
        key += (torch.is_inference_mode_enabled(),)
        entries = self._inference_cache.setdefault(graph, {})
        entry = entries.get(name)
        if entry is None or entry[0] != key:
            entry = entries[name] = (key, build())
        return entry[1]

    def _interpolate_kernels(self, graph: Graph) -> Tensor:
        n_knots = self.weight.shape[0]
        interp = interpolation_matrix(graph, self.kernel_size, self.weight.dtype)
        return (interp @ self.weight.view(n_knots, -1)).view(-1, self.in_channels, self.out_channels)

    def forward(self, x: Tensor, graph: Graph, kernels: Tensor | None = None) -> Tensor:
        """``(B, N, in) -> (B, N, out)`` on ``graph`` (N nodes).

        ``kernels``: this layer's :meth:`edge_kernels` on ``graph``, computed once
        by a caller that applies the layer many times with the same weights
        (a recurrent cell over time steps).
        """
        if x.dim() != 3 or x.shape[1] != graph.num_nodes or x.shape[2] != self.in_channels:
            raise InputError(
                f"SplineConv expects x of shape (B, {graph.num_nodes}, {self.in_channels}), got {tuple(x.shape)}"
            )
        if graph.pseudo.shape[1] != self.dim:
            raise InputError(f"graph pseudo-coordinates have {graph.pseudo.shape[1]} dims, layer expects {self.dim}")
        if self.active_method() == "edges":
            out = self._edges(x, graph, self.edge_kernels(graph) if kernels is None else kernels)
        else:
            out = self._sparse(x, graph, kernels)
        if self.bias is not None:
            out = out + self.bias
        return out.contiguous()

    def _edges(self, x: Tensor, graph: Graph, kernel: Tensor) -> Tensor:
        """Gather, per-edge matmul, scatter-add."""
        batch, n, _ = x.shape
        src, dst = graph.edge_index[0], graph.edge_index[1]
        # node-major (N, B, C): gathers and scatters move whole contiguous rows (measured fastest on CPU)
        xt = x.transpose(0, 1).contiguous()
        xj = xt.index_select(0, src)  # (E, B, in)
        # bmm even for in=1: its backward beat a broadcast product 2x here
        msg = torch.bmm(xj, kernel)  # (E, B, out)
        out = msg.new_zeros(n, batch, self.out_channels).index_add_(0, dst, msg)  # msg's dtype: autocast's
        if self.aggr == "mean":
            degree = torch.bincount(dst, minlength=n).clamp_(min=1).to(out.dtype)
            out = out / degree.view(n, 1, 1)
        if self.root is not None:
            out = torch.addmm(out.view(n * batch, -1), xt.view(n * batch, -1), self.root).view(n, batch, -1)
        return out.transpose(0, 1)

    def _blocks(self, graph: Graph, kernels: Tensor, degree: Tensor) -> Tensor:
        """The matrix entries ``(M, in, out)``: edge kernels (over the in-``degree`` for mean), then root blocks."""
        if self.aggr == "mean":
            kernels = kernels / degree[graph.edge_index[1]].to(kernels.dtype).view(-1, 1, 1)
        if self.root is not None:
            kernels = torch.cat([kernels, self.root.expand(graph.num_nodes, self.in_channels, self.out_channels)])
        return kernels

    def _sparse(self, x: Tensor, graph: Graph, kernels: Tensor | None) -> Tensor:
        """One block-sparse CSR product ``(N out, N in) @ (N in, B)``."""
        batch, n, cin = x.shape
        cols = x.permute(1, 2, 0).reshape(n * cin, batch)
        if torch.is_grad_enabled():
            pattern = _block_pattern(graph, cin, self.out_channels, self.root is not None)
            if kernels is None:
                kernels = self.edge_kernels(graph)
            y = _BlockSparseProduct.apply(cols, self._blocks(graph, kernels, pattern.degree), pattern)
        else:
            y = self.operator(graph, batch) @ cols
        return y.view(n, self.out_channels, batch).permute(2, 0, 1)

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, dim={self.dim}, kernel_size={self.kernel_size}, "
            f"degree={self.degree}, aggr={self.aggr!r}, root_weight={self.root is not None}, "
            f"bias={self.bias is not None}, method={self.method!r}"
        )
