"""ResidualGraphBlock: wiring against the direct formula, skip path, gradients."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn.functional import elu

from learner.graph import Graph
from learner.nn import ResidualGraphBlock, SplineConv
from shared.errors import InputError


@pytest.fixture(scope="module")
def graph() -> Graph:
    rng = np.random.default_rng(0)
    return Graph.from_edges(rng.normal(size=(15, 3)), rng.integers(0, 15, size=(40, 2)))


def _randomise(module: torch.nn.Module, seed: int = 0) -> None:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(0.5 * torch.randn(p.shape, generator=gen, dtype=p.dtype))


@pytest.mark.parametrize("cin, cout, activation", [(3, 5, True), (4, 4, True), (4, 2, False)])
def test_matches_direct_formula(graph, cin, cout, activation):
    block = ResidualGraphBlock(cin, cout, activation=activation).double()
    _randomise(block)
    x = torch.randn(2, 15, cin, dtype=torch.float64)
    skip = x if cin == cout else x @ block.skip.weight.T
    y = block.conv2(elu(block.conv1(x, graph)), graph) + skip
    expected = elu(y) if activation else y
    out = block(x, graph)
    assert out.shape == (2, 15, cout)
    torch.testing.assert_close(out, expected)


@pytest.mark.parametrize("cin, cout, activation", [(3, 5, True), (4, 4, True), (4, 2, False)])
def test_inference_on_the_column_layout_matches_training_path(graph, cin, cout, activation):
    block = ResidualGraphBlock(cin, cout, activation=activation).double()
    _randomise(block)
    assert block.conv1.inference_method == block.conv2.inference_method == "sparse"
    x = torch.randn(3, 15, cin, dtype=torch.float64)
    expected = block(x, graph)
    with torch.no_grad():
        out = block(x, graph)
        chained = block(out, graph) if cin == cout else None  # reads the column-layout view it returned
    torch.testing.assert_close(out, expected)
    if chained is not None:
        torch.testing.assert_close(chained, block(expected, graph).detach())


def test_skip_is_identity_when_widths_match(graph):
    block = ResidualGraphBlock(4, 4).double()
    assert isinstance(block.skip, torch.nn.Identity)
    with torch.no_grad():  # silence the convolutional path
        for p in block.conv2.parameters():
            p.zero_()
    x = torch.randn(2, 15, 4, dtype=torch.float64)
    torch.testing.assert_close(block(x, graph), elu(x))


def test_projection_skip_has_no_bias():
    block = ResidualGraphBlock(3, 6)
    assert isinstance(block.skip, torch.nn.Linear) and block.skip.bias is None
    assert isinstance(block.conv1, SplineConv) and block.conv1.in_channels == 3 and block.conv2.in_channels == 6
    n_params = sum(p.numel() for p in block.parameters())
    assert n_params == (27 * 3 * 6 + 3 * 6 + 6) + (27 * 6 * 6 + 6 * 6 + 6) + 3 * 6


def test_gradcheck(graph):
    block = ResidualGraphBlock(2, 3).double()
    x = torch.randn(1, 15, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: block(x, graph), (x,))
    block(x, graph).square().sum().backward()
    assert all(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in block.parameters())


def test_reset_parameters_and_repr(graph):
    block = ResidualGraphBlock(3, 4, activation=False)
    before = [p.detach().clone() for p in block.parameters()]
    block.reset_parameters()
    assert any(not torch.equal(a, b) for a, b in zip(before, block.parameters()))
    assert repr(block).startswith("ResidualGraphBlock(\n  3, 4, activation=False\n  (conv1): SplineConv(3, 4,")
    with pytest.raises(InputError, match="expects"):
        block(torch.zeros(1, 15, 4), graph)
