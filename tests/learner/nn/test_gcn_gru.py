"""GCN-GRU: the fused gate convolutions equal the four-convolution equations; sequences and gradients."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.graph import Graph
from learner.nn import GCNGRU, GCNGRUCell, SplineConv
from shared.errors import InputError

N, CIN, H = 12, 3, 4


@pytest.fixture(scope="module")
def graph() -> Graph:
    rng = np.random.default_rng(1)
    return Graph.from_edges(rng.normal(size=(N, 3)), rng.integers(0, N, size=(30, 2)))


def _cell(seed: int = 0) -> GCNGRUCell:
    torch.manual_seed(seed)
    cell = GCNGRUCell(CIN, H).double()
    with torch.no_grad():
        for p in cell.parameters():
            p.normal_(0.0, 0.4)
    return cell


def _split(conv: SplineConv, cols: slice) -> SplineConv:
    """A stand-alone convolution computing the output columns ``cols`` of ``conv``."""
    out = SplineConv(conv.in_channels, cols.stop - cols.start).double()
    with torch.no_grad():
        out.weight.copy_(conv.weight[..., cols])
        out.root.copy_(conv.root[:, cols])
        out.bias.copy_(conv.bias[cols])
    return out


def test_cell_matches_gru_equations_with_separate_convolutions(graph):
    cell = _cell()
    rz, n = slice(0, 2 * H), slice(2 * H, 3 * H)
    conv_x_rz, conv_x_n = _split(cell.conv_x, rz), _split(cell.conv_x, n)
    conv_h_rz, conv_h_n = _split(cell.conv_h, rz), _split(cell.conv_h, n)
    x = torch.randn(2, N, CIN, dtype=torch.float64)
    h = torch.randn(2, N, H, dtype=torch.float64)
    gates = torch.sigmoid(conv_x_rz(x, graph) + conv_h_rz(h, graph))
    r, z = gates[..., :H], gates[..., H:]
    cand = torch.tanh(conv_x_n(x, graph) + r * conv_h_n(h, graph))
    expected = (1 - z) * cand + z * h
    torch.testing.assert_close(cell(x, h, graph), expected)


def test_no_hidden_state_means_zeros(graph):
    cell = _cell(1)
    x = torch.randn(3, N, CIN, dtype=torch.float64)
    torch.testing.assert_close(cell(x, None, graph), cell(x, torch.zeros(3, N, H, dtype=torch.float64), graph))


def test_sequence_equals_repeated_cell_steps(graph):
    gru = GCNGRU(CIN, H).double()
    x = torch.randn(2, 5, N, CIN, dtype=torch.float64)
    h0 = torch.randn(2, N, H, dtype=torch.float64)
    for init in (None, h0):
        states = gru(x, graph, init)
        assert states.shape == (2, 5, N, H)
        h = init
        for t in range(5):
            h = gru.cell(x[:, t], h, graph)
            torch.testing.assert_close(states[:, t], h)


def test_gradients(graph):
    gru = GCNGRU(2, 2).double()
    x = torch.randn(1, 3, N, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: gru(x, graph), (x,))
    gru(x, graph)[:, -1].square().sum().backward()
    assert all(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in gru.parameters())


def test_bad_shapes_and_repr(graph):
    gru = GCNGRU(CIN, H)
    with pytest.raises(InputError, match=r"\(B, T, 12, 3\)"):
        gru(torch.zeros(2, N, CIN), graph)
    with pytest.raises(InputError, match="hidden state"):
        gru.cell(torch.zeros(2, N, CIN), torch.zeros(2, N, H + 1), graph)
    assert repr(gru).startswith("GCNGRU(\n  3, 4\n  (cell): GCNGRUCell(\n    3, 4\n")
    assert "(conv_h): SplineConv(4, 12," in repr(gru)
