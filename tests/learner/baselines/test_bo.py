"""Budgeted Bayesian minimisation: finds a known minimum, spends exactly its budget, is reproducible."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learner.baselines.bo import BOSettings, bayes_minimise
from shared.errors import InputError

FAST = {"restarts": 4, "raw_samples": 64}


def _bowl(x: np.ndarray) -> float:
    return float(((x - np.array([0.3, -0.2])) ** 2).sum())


def test_finds_the_minimum_of_a_quadratic_bowl_within_its_budget():
    trace = bayes_minimise(_bowl, [[-1.0, -1.0], [1.0, 1.0]], BOSettings(budget=15, seed=0, **FAST))
    assert trace.x.shape == (15, 2) and trace.f.shape == (15,)
    assert np.all((trace.x >= -1.0) & (trace.x <= 1.0))
    np.testing.assert_allclose([_bowl(x) for x in trace.x], trace.f)
    # the 5-point Sobol design alone is far off; the GP steps close in on (0.3, -0.2)
    assert trace.f[trace.best] < 1e-2 < trace.f[:5].min()
    np.testing.assert_allclose(trace.x[trace.best], [0.3, -0.2], atol=0.1)


def test_is_reproducible_and_leaves_torch_global_state_alone():
    settings = BOSettings(budget=7, seed=3, **FAST)
    state, threads = torch.get_rng_state(), torch.get_num_threads()
    a = bayes_minimise(_bowl, [[-1.0, -1.0], [1.0, 1.0]], settings)
    assert torch.equal(torch.get_rng_state(), state) and torch.get_num_threads() == threads
    b = bayes_minimise(_bowl, [[-1.0, -1.0], [1.0, 1.0]], settings)
    np.testing.assert_array_equal(a.x, b.x)
    c = bayes_minimise(_bowl, [[-1.0, -1.0], [1.0, 1.0]], BOSettings(budget=7, seed=4, **FAST))
    assert not np.array_equal(a.x[:5], c.x[:5])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"budget": 0}, "budget must be >= 1"),
        ({"budget": 4, "initial": 5}, "smaller than the initial design"),
        ({"initial": 0}, "initial design size"),
        ({"seed": -1}, "seed"),
        ({"restarts": 0}, "restarts"),
    ],
)
def test_settings_refuse_bad_values(kwargs, message):
    with pytest.raises(InputError, match=message):
        BOSettings(**kwargs)


def test_refuses_a_budget_below_the_default_design_bad_bounds_and_bad_values():
    with pytest.raises(InputError, match=r"initial design \(7 points for 3 parameters\)"):
        bayes_minimise(_bowl, np.tile([[0.0], [1.0]], 3), BOSettings(budget=6))
    with pytest.raises(InputError, match="bounds must have shape"):
        bayes_minimise(_bowl, [0.0, 1.0])
    with pytest.raises(InputError, match="lower < upper"):
        bayes_minimise(_bowl, [[0.0, 1.0], [0.0, 2.0]])
    with pytest.raises(InputError, match="finite and >= 0"):
        bayes_minimise(lambda x: float("nan"), [[0.0], [1.0]], BOSettings(budget=3))
