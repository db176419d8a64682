"""ConditionalGatedTransition against its defining equations (numpy, float64), initialisation,
bounded state and errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.nn import ConditionalGatedTransition
from shared.errors import InputError

L = 6


def _elu(v):
    return np.where(v > 0, v, np.expm1(np.minimum(v, 0)))


def _reference(module: ConditionalGatedTransition, z: np.ndarray, c: np.ndarray | None) -> np.ndarray:
    p = {k: v.detach().double().numpy() for k, v in module.named_parameters()}

    def affine(i):
        y = p[f"alpha{i}"] * z + p[f"gamma{i}"]
        return y if c is None else y + p[f"beta{i}"] * c

    def lin(i, v):
        return v @ p[f"lin{i}.weight"].T + p[f"lin{i}.bias"]

    g = 1 / (1 + np.exp(-lin(1, _elu(affine(1)))))
    h = _elu(lin(2, _elu(affine(2))))
    out = (1 - g) * lin(3, affine(3)) + g * h
    if "norm.weight" not in p:
        return out
    centred = out - out.mean(-1, keepdims=True)
    return centred / np.sqrt((centred**2).mean(-1, keepdims=True) + 1e-5) * p["norm.weight"] + p["norm.bias"]


def _randomised(conditioned: bool, normalize: bool = True) -> ConditionalGatedTransition:
    torch.manual_seed(0)
    t = ConditionalGatedTransition(L, conditioned=conditioned, normalize=normalize).double()
    with torch.no_grad():
        for p in t.parameters():
            p.normal_(0.0, 0.7)
    return t


@pytest.mark.parametrize("normalize", [True, False])
@pytest.mark.parametrize("conditioned", [True, False])
def test_matches_spec_equations(conditioned, normalize):
    t = _randomised(conditioned, normalize)
    rng = np.random.default_rng(0)
    z = rng.normal(size=(3, 5, L))
    c = rng.normal(size=(3, 5, L)) if conditioned else None
    out = t(torch.from_numpy(z), None if c is None else torch.from_numpy(c))
    np.testing.assert_allclose(out.detach().numpy(), _reference(t, z, c), rtol=1e-12, atol=1e-12)


def test_parameters():
    names = {n for n, _ in ConditionalGatedTransition(L).named_parameters()}
    assert {f"{k}{i}" for k in ("alpha", "beta", "gamma") for i in (1, 2, 3)} <= names
    pns = {n for n, _ in ConditionalGatedTransition(L, conditioned=False).named_parameters()}
    assert not any(n.startswith("beta") for n in pns) and len(names - pns) == 3


@pytest.mark.parametrize("normalize", [True, False])
def test_linear_path_starts_at_identity(normalize):
    t = ConditionalGatedTransition(L, normalize=normalize).double()
    torch.testing.assert_close(t.lin3.weight, torch.eye(L, dtype=torch.float64))
    with torch.no_grad():  # close the gate: only the linear path remains
        t.lin1.weight.zero_()
        t.lin1.bias.fill_(-60.0)
    z, c = torch.randn(2, 4, L, dtype=torch.float64), torch.randn(2, 4, L, dtype=torch.float64)
    expected = torch.nn.functional.layer_norm(z, (L,)) if normalize else z
    torch.testing.assert_close(t(z, c), expected)


def test_state_stays_bounded_under_an_expansive_linear_path():
    """Gain 1.5 on the linear path over 55 frames: the normalised state keeps its size, the reference's explodes."""
    sizes = {}
    for normalize in (True, False):
        t = ConditionalGatedTransition(L, normalize=normalize).double()
        with torch.no_grad():
            t.lin3.weight.mul_(1.5)
            t.lin1.weight.zero_()
            t.lin1.bias.fill_(-60.0)  # gate closed: the linear path alone
        z, c = torch.randn(3, 4, L, dtype=torch.float64), torch.zeros(3, 4, L, dtype=torch.float64)
        with torch.no_grad():
            for _ in range(55):
                z = t(z, c)
        sizes[normalize] = float(z.abs().max())
    assert sizes[True] <= L**0.5 + 1e-6  # unit variance per node, unit scale, zero shift: |z_i| <= sqrt(L)
    assert sizes[False] > 1.5**50


def test_condition_matters_and_gets_gradients_at_init():
    t = ConditionalGatedTransition(L)
    z = torch.randn(2, 4, L)
    c = torch.randn(2, 4, L, requires_grad=True)
    out = t(z, c)
    assert not torch.allclose(out, t(z, torch.zeros_like(c)))
    out.sum().backward()
    assert bool(c.grad.abs().sum() > 0)


def test_condition_broadcasts_over_the_batch():
    t = _randomised(True)
    z = torch.randn(4, 5, L, dtype=torch.float64)
    c = torch.randn(1, 5, L, dtype=torch.float64)
    torch.testing.assert_close(t(z, c), t(z, c.expand(4, 5, L)))


def test_gradcheck():
    t = _randomised(True)
    z = torch.randn(2, 3, L, dtype=torch.float64, requires_grad=True)
    c = torch.randn(2, 3, L, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(t, (z, c))


def test_errors_and_repr():
    t = ConditionalGatedTransition(L)
    z = torch.zeros(2, 3, L)
    with pytest.raises(InputError, match="needs c"):
        t(z)
    with pytest.raises(InputError, match="broadcast"):
        t(z, torch.zeros(3, 3, L))
    with pytest.raises(InputError, match="channels"):
        t(torch.zeros(2, 3, L + 1), z)
    with pytest.raises(InputError, match="takes no c"):
        ConditionalGatedTransition(L, conditioned=False)(z, z)
    assert "latent=6, conditioned=True" in repr(t)
