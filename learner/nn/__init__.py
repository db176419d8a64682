"""Graph neural-network layers: spline convolution, residual blocks, GCN-GRU, gated transition."""

from __future__ import annotations

from learner.nn.gated_transition import ConditionalGatedTransition
from learner.nn.gcn_gru import GCNGRU, GCNGRUCell
from learner.nn.residual_block import ResidualGraphBlock
from learner.nn.spline_conv import SplineConv, spline_basis

__all__ = ["spline_basis", "SplineConv", "ResidualGraphBlock", "GCNGRUCell", "GCNGRU", "ConditionalGatedTransition"]
