r"""Residual block of two spline convolutions with a 1x1 skip.

.. math::

    h = \mathrm{ELU}(\mathrm{conv}_1(x)), \qquad
    y = \mathrm{ELU}(\mathrm{conv}_2(h) + S x)

with :math:`S` the identity when the widths match and a bias-free 1x1
(per-node linear) map otherwise; ``activation=False`` drops the outer ELU.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.functional import elu

from learner.graph.hierarchy import Graph
from learner.nn.spline_conv import SplineConv

__all__ = ["ResidualGraphBlock"]


class ResidualGraphBlock(nn.Module):
    """Two :class:`SplineConv` layers plus a skip connection, ``(B, N, in) -> (B, N, out)``.

    Parameters
    ----------
    in_channels, out_channels : feature sizes.
    activation : apply the final ELU (a decoder's last block may want raw outputs).
    dim, kernel_size : passed to both convolutions.
    """

    def __init__(
        self, in_channels: int, out_channels: int, activation: bool = True, dim: int = 3, kernel_size: int = 3
    ) -> None:
        super().__init__()
        self.in_channels, self.out_channels, self.activation = in_channels, out_channels, activation
        self.conv1 = SplineConv(in_channels, out_channels, dim=dim, kernel_size=kernel_size)
        self.conv2 = SplineConv(out_channels, out_channels, dim=dim, kernel_size=kernel_size)
        # conv2 already carries a bias, so the projection needs none
        self.skip = nn.Linear(in_channels, out_channels, bias=False) if in_channels != out_channels else nn.Identity()
        self.reset_parameters()

    def reset_parameters(self) -> None:
        self.conv1.reset_parameters()
        self.conv2.reset_parameters()
        if isinstance(self.skip, nn.Linear):
            self.skip.reset_parameters()

    def forward(self, x: Tensor, graph: Graph) -> Tensor:
        if not torch.is_grad_enabled() and self.conv1.inference_method == self.conv2.inference_method == "sparse":
            return self._forward_columns(x, graph)
        y = self.conv2(elu(self.conv1(x, graph)), graph) + self.skip(x)
        return elu(y) if self.activation else y

    def _forward_columns(self, x: Tensor, graph: Graph) -> Tensor:
        """Inference with both convolutions on the ``(N C, B)`` layout: one transpose in, none out.

        Returns a ``(B, N, out)`` view of the column-layout result, so a next
        block on the same layout reads it without a copy.
        """
        b, n, cin = x.shape
        cols = x.permute(1, 2, 0).reshape(n * cin, b)
        h = elu(self.conv1.columns(cols, graph), inplace=True)
        y = self.conv2.columns(h, graph).view(n, self.out_channels, b)
        y += self.skip(x).permute(1, 2, 0)
        if self.activation:
            elu(y, inplace=True)
        return y.permute(2, 0, 1)

    def extra_repr(self) -> str:
        return f"{self.in_channels}, {self.out_channels}, activation={self.activation}"
