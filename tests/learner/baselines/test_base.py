"""The baseline contract: tissue from excitability, exact budgets, reproducible fits, refused input."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

import learner
from learner.baselines import FSBO, VAEBO, diffusivity_from_excitability, fields_from_excitability
from learner.observations import Observations
from shared.errors import InputError

FAST = {"restarts": 4, "raw_samples": 64}


def test_diffusivity_follows_excitability_from_healthy_to_scar():
    t = fields_from_excitability([0.15, 0.3, 0.5, 0.4, 0.2])
    np.testing.assert_allclose(t.D, [1.0, 1.0 - 0.9 * 0.15 / 0.35, 0.1, 1.0 - 0.9 * 0.25 / 0.35, 1.0 - 0.9 / 7])
    np.testing.assert_array_equal(t.label, [0, 1, 2, 2, 0])
    np.testing.assert_allclose(diffusivity_from_excitability([0.05, 0.6]), [1.0, 0.1])


@pytest.fixture(scope="module")
def context(lv) -> Observations:
    a = np.full(lv.mesh.n_nodes, 0.15)
    a[:60] = 0.5
    return lv.observe(fields_from_excitability(a), lv.sites[:2])


def test_fit_spends_exactly_its_budget_and_is_reproducible(lv, context, counting):
    baseline = FSBO(regions=2, budget=7, seed=0, simulator=counting, **FAST)
    assert repr(baseline) == "FSBO(regions=2, a_bounds=(0.15, 0.5), budget=7, seed=0)"
    result = baseline.fit(context, lv.solver)
    assert result.calls == counting.calls == len(result.history) == 7
    assert result.sequences == counting.sequences == 14
    assert result.objective == result.history.min()
    assert np.all(np.diff(result.best_so_far) <= 0)
    assert 0 < result.simulate_seconds < result.seconds and 0 <= result.setup_seconds < result.seconds
    assert result.params.shape == (2,) and np.all((result.params >= 0.15) & (result.params <= 0.5))
    np.testing.assert_array_equal(result.tissue.a, baseline.tissue_at(result.params).a)

    again = FSBO(regions=2, budget=7, seed=0, **FAST).fit(context, lv.solver)
    np.testing.assert_array_equal(again.history, result.history)
    np.testing.assert_array_equal(again.params, result.params)
    other = FSBO(regions=2, budget=7, seed=1, **FAST).fit(context, lv.solver)
    assert not np.array_equal(other.history, result.history)

    u = baseline.predict(lv.sites[2:4])
    assert u.shape == (2, 12, lv.mesh.n_nodes) and u.dtype == np.float32
    assert counting.calls == 8  # predict is one more call, not counted in the fit


def test_budget_below_the_initial_design_is_refused():
    with pytest.raises(InputError, match=r"budget \(14\) is smaller than the initial design \(15 points"):
        FSBO(budget=14)
    with pytest.raises(InputError, match=r"budget \(5\) is smaller than the initial design \(6\)"):
        FSBO(regions=2, budget=5, initial=6)
    with pytest.raises(InputError, match=r"initial design \(7 points for 3 parameters\)"):
        VAEBO(latent=3, budget=6)
    with pytest.raises(InputError, match="no simulator plug-in 'nope'"):
        FSBO(simulator="nope")


def test_empty_nan_or_mismatched_observations_are_refused(lv, context):
    baseline = FSBO(regions=2, budget=5, **FAST)
    with pytest.raises(InputError, match="has not been fitted"):
        baseline.predict([0])
    with pytest.raises(InputError, match="context size must be >= 1"):
        Observations(lv.mesh, np.zeros(0, int), np.zeros((0, 12, lv.mesh.n_nodes)), context.observed, context.times)
    with pytest.raises(InputError, match="no observed node"):
        dataclasses.replace(context, observed=np.zeros(lv.mesh.n_nodes, bool))
    blind = dataclasses.replace(context, observed=context.observed.copy())
    blind.observed[:] = False  # after construction, past Observations' own check
    with pytest.raises(InputError, match="no node is observed"):
        baseline.fit(blind, lv.solver)
    holed = dataclasses.replace(context, obs=context.obs.copy())
    holed.obs[1, 4, 7] = np.nan  # after construction, past Observations' own check
    with pytest.raises(InputError, match="NaN or inf at observed nodes"):
        baseline.fit(holed, lv.solver)
    with pytest.raises(InputError, match="simulates 10 frames but the observations have 12"):
        baseline.fit(context, {**lv.solver, "frames": 10})
    with pytest.raises(InputError, match="must be learner.observations.Observations"):
        baseline.fit(context.obs, lv.solver)
    assert baseline.result is None


def test_predict_refuses_sites_outside_the_mesh(lv, context):
    baseline = FSBO(regions=1, budget=3, **FAST)
    baseline.fit(context, lv.solver)
    for bad in ([], [lv.mesh.n_nodes], [-1], [[0, 1]]):
        with pytest.raises(InputError, match="sites|not nodes"):
            baseline.predict(bad)


def test_learner_never_imports_simgen():
    """The simulator is a plug-in (shared.simulator); a static import would break the dependency direction."""
    root = Path(learner.__file__).parent
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not any(n == "simgen" or n.startswith("simgen.") for n in names), f"{path} imports simgen"
