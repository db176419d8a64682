r"""Graph-convolutional GRU: a GRU whose gates are spline convolutions over the nodes.

.. math::

    [r, z] &= \sigma(\mathrm{conv}_{x,rz}(x) + \mathrm{conv}_{h,rz}(h)) \\
    n &= \tanh(\mathrm{conv}_{x,n}(x) + r \odot \mathrm{conv}_{h,n}(h)) \\
    h' &= (1 - z) \odot n + z \odot h

The three input convolutions (and the three hidden ones) share their
neighbourhood, so they run as one convolution with ``3 * hidden`` outputs
(column blocks r, z, n), which is the same map as three separate layers.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from learner.graph.hierarchy import Graph
from learner.nn.spline_conv import SplineConv
from shared.errors import InputError

__all__ = ["GCNGRUCell", "GCNGRU"]


class GCNGRUCell(nn.Module):
    """One GRU step on graph node features: ``x (B, N, in)``, ``h (B, N, H) | None -> h' (B, N, H)``.

    Parameters
    ----------
    input_size, hidden_size : channels of ``x`` and ``h``.
    dim, kernel_size : passed to the spline convolutions.
    """

    def __init__(self, input_size: int, hidden_size: int, dim: int = 3, kernel_size: int = 3) -> None:
        super().__init__()
        self.input_size, self.hidden_size = input_size, hidden_size
        self.conv_x = SplineConv(input_size, 3 * hidden_size, dim=dim, kernel_size=kernel_size)
        self.conv_h = SplineConv(hidden_size, 3 * hidden_size, dim=dim, kernel_size=kernel_size)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        self.conv_x.reset_parameters()
        self.conv_h.reset_parameters()

    def input_gates(self, x: Tensor, graph: Graph) -> Tensor:
        """``conv_x(x)``: the input half of every gate, ``(B, N, 3H)`` (independent of ``h``)."""
        return self.conv_x(x, graph)

    def step(self, gx: Tensor, h: Tensor | None, graph: Graph, kernels: Tensor | None = None) -> Tensor:
        """The update from precomputed input gates ``gx`` (see :meth:`input_gates`).

        ``kernels``: ``conv_h.edge_kernels(graph)``, computed once per sequence by the caller.
        """
        hs = self.hidden_size
        if h is None:
            # conv_h(0) is its bias alone; skip the convolution
            gh = self.conv_h.bias if self.conv_h.bias is not None else gx.new_zeros(3 * hs)
            h = gx.new_zeros(*gx.shape[:-1], hs)
        else:
            if h.shape != (*gx.shape[:-1], hs):
                raise InputError(f"hidden state must have shape {(*gx.shape[:-1], hs)}, got {tuple(h.shape)}")
            gh = self.conv_h(h, graph, kernels)
        r, z = torch.sigmoid(gx[..., : 2 * hs] + gh[..., : 2 * hs]).chunk(2, dim=-1)
        n = torch.tanh(gx[..., 2 * hs :] + r * gh[..., 2 * hs :])
        return (1 - z) * n + z * h

    def forward(self, x: Tensor, h: Tensor | None, graph: Graph) -> Tensor:
        return self.step(self.input_gates(x, graph), h, graph)

    def extra_repr(self) -> str:
        return f"{self.input_size}, {self.hidden_size}"


class GCNGRU(nn.Module):
    """A :class:`GCNGRUCell` run over a sequence ``x (B, T, N, in) -> (B, T, N, H)`` (all hidden states).

    The input convolutions of all frames run as one batch; only the hidden
    convolution is sequential (its edge kernels are interpolated once).
    """

    def __init__(self, input_size: int, hidden_size: int, dim: int = 3, kernel_size: int = 3) -> None:
        super().__init__()
        self.input_size, self.hidden_size = input_size, hidden_size
        self.cell = GCNGRUCell(input_size, hidden_size, dim=dim, kernel_size=kernel_size)

    def reset_parameters(self) -> None:
        self.cell.reset_parameters()

    def forward(self, x: Tensor, graph: Graph, h0: Tensor | None = None) -> Tensor:
        """Hidden states after every frame; ``h0`` (B, N, H) defaults to zeros."""
        if x.dim() != 4 or x.shape[2] != graph.num_nodes or x.shape[3] != self.input_size:
            raise InputError(
                f"GCNGRU expects x of shape (B, T, {graph.num_nodes}, {self.input_size}), got {tuple(x.shape)}"
            )
        b, t, n, c = x.shape
        gx = self.cell.input_gates(x.reshape(b * t, n, c), graph).view(b, t, n, -1)
        kernels = self.cell.conv_h.edge_kernels(graph)  # the same weights at every step
        h, states = h0, []
        for k in range(t):
            h = self.cell.step(gx[:, k], h, graph, kernels)
            states.append(h)
        return torch.stack(states, dim=1)

    def extra_repr(self) -> str:
        return f"{self.input_size}, {self.hidden_size}"
