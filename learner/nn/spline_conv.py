r"""Continuous B-spline kernel graph convolution (SplineCNN, Fey et al. 2018), degree 1.

.. math::

    x'_i = \frac{1}{|\mathcal N(i)|} \sum_{j \to i} x_j\, W(u_{ji})
           + x_i W_{\mathrm{root}} + b,
    \qquad W(u) = \sum_{s} B_s(u)\, W_{k_s(u)}

with :math:`u_{ji} \in [0,1]^D` the edge pseudo-coordinates and
:math:`W(u)` the multilinear interpolation of ``kernel_size**D`` weight
matrices on a regular grid of knots (open B-splines of degree 1).
"""

from __future__ import annotations

import math
import weakref

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import Graph
from shared.errors import InputError

__all__ = ["spline_basis", "interpolation_matrix", "SplineConv"]

_AGGREGATIONS = ("mean", "add")

# interpolation matrices per graph: the basis costs more than the kernel matmul, and graphs are reused
_INTERPOLATION_CACHE: weakref.WeakKeyDictionary[Graph, dict[tuple, Tensor]] = weakref.WeakKeyDictionary()


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
    ) -> None:
        super().__init__()
        if degree != 1:
            raise InputError(f"SplineConv supports degree=1 only, got degree={degree}")
        if aggr not in _AGGREGATIONS:
            raise InputError(f"aggr must be one of {_AGGREGATIONS}, got {aggr!r}")
        if min(in_channels, out_channels, dim) < 1 or kernel_size < 2:
            raise InputError(
                f"need in/out channels >= 1, dim >= 1, kernel_size >= 2; got {in_channels}, {out_channels}, "
                f"{dim}, {kernel_size}"
            )
        self.in_channels, self.out_channels = in_channels, out_channels
        self.dim, self.kernel_size, self.degree, self.aggr = dim, kernel_size, degree, aggr
        self.weight = nn.Parameter(torch.empty(kernel_size**dim, in_channels, out_channels))
        self.root = nn.Parameter(torch.empty(in_channels, out_channels)) if root_weight else None
        self.bias = nn.Parameter(torch.empty(out_channels)) if bias else None
        self.reset_parameters()

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
        """Interpolated kernel of every edge, ``(E, in, out)``."""
        n_knots = self.weight.shape[0]
        interp = interpolation_matrix(graph, self.kernel_size, self.weight.dtype)
        return (interp @ self.weight.view(n_knots, -1)).view(-1, self.in_channels, self.out_channels)

    def forward(self, x: Tensor, graph: Graph) -> Tensor:
        """``(B, N, in) -> (B, N, out)`` on ``graph`` (N nodes)."""
        if x.dim() != 3 or x.shape[1] != graph.num_nodes or x.shape[2] != self.in_channels:
            raise InputError(
                f"SplineConv expects x of shape (B, {graph.num_nodes}, {self.in_channels}), got {tuple(x.shape)}"
            )
        if graph.pseudo.shape[1] != self.dim:
            raise InputError(f"graph pseudo-coordinates have {graph.pseudo.shape[1]} dims, layer expects {self.dim}")
        batch, n, _ = x.shape
        src, dst = graph.edge_index[0], graph.edge_index[1]
        kernel = self.edge_kernels(graph)
        # node-major (N, B, C): gathers and scatters move whole contiguous rows (measured fastest on CPU)
        xt = x.transpose(0, 1).contiguous()
        xj = xt.index_select(0, src)  # (E, B, in)
        # bmm even for in=1: its backward beat a broadcast product 2x here
        msg = torch.bmm(xj, kernel)  # (E, B, out)
        out = xt.new_zeros(n, batch, self.out_channels).index_add_(0, dst, msg)
        if self.aggr == "mean":
            degree = torch.bincount(dst, minlength=n).clamp_(min=1).to(out.dtype)
            out = out / degree.view(n, 1, 1)
        if self.root is not None:
            out = torch.addmm(out.view(n * batch, -1), xt.view(n * batch, -1), self.root).view(n, batch, -1)
        if self.bias is not None:
            out = out + self.bias
        return out.transpose(0, 1).contiguous()

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, dim={self.dim}, kernel_size={self.kernel_size}, "
            f"degree={self.degree}, aggr={self.aggr!r}, root_weight={self.root is not None}, "
            f"bias={self.bias is not None}"
        )
