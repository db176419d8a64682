"""FS-BO recovers a scar in one mesh region within a small budget, from potentials or from the 12-lead ECG, and
predicts targets better than healthy."""

from __future__ import annotations

import numpy as np

from learner.baselines import FSBO, fields_from_excitability, geodesic_scar, mesh_regions
from shared.tissue import LABEL_BORDER, LABEL_CORE, TissueFields


def _data_like_scar(a: np.ndarray) -> TissueFields:
    """The data's materials (core a 0.5 D 0.1, border a 0.3 D 0.5), not FS-BO's D(a) line."""
    core, border = a == 0.5, a == 0.3
    return TissueFields(
        a=a,
        D=np.where(core, 0.1, np.where(border, 0.5, 1.0)),
        label=np.where(core, LABEL_CORE, np.where(border, LABEL_BORDER, 0)).astype(np.int8),
    )


def _scar_in_region(lv, region: int) -> TissueFields:
    labels = mesh_regions(lv.mesh)
    members = np.flatnonzero(labels == region)
    centre = members[np.argmin(((lv.mesh.points[members] - lv.mesh.points[members].mean(0)) ** 2).sum(1))]
    return _data_like_scar(geodesic_scar(lv.mesh, int(centre), 25.0, lv.mesh.mean_edge_length()))


def _healthy_and_fitted_mse(lv, baseline, truth, targets) -> tuple[float, float]:
    u_true = lv.simulator.simulate(lv.mesh, truth, targets, lv.solver)
    u_healthy = lv.simulator.simulate(
        lv.mesh, fields_from_excitability(np.full(lv.mesh.n_nodes, 0.15)), targets, lv.solver
    )
    return float(np.mean((u_healthy - u_true) ** 2)), float(np.mean((baseline.predict(targets) - u_true) ** 2))


def test_fitted_to_the_ecg_it_predicts_targets_better_than_healthy(lv):
    """The same scar, recorded only as the 12-lead ECGs of the context pacings."""
    truth = _scar_in_region(lv, 3)
    context, targets = lv.sites[:3], lv.sites[3:]
    baseline = FSBO(budget=25, seed=0, restarts=4, raw_samples=64)
    result = baseline.fit(lv.observe_ecg(truth, context), lv.solver)
    assert result.calls == 25 and int(np.argmax(result.params)) == 3
    healthy, fitted = _healthy_and_fitted_mse(lv, baseline, truth, targets)
    assert fitted < 0.5 * healthy


def test_recovers_the_scarred_region_and_beats_healthy_on_targets(lv):
    region = 3
    truth = _scar_in_region(lv, region)
    assert (mesh_regions(lv.mesh)[truth.label == LABEL_CORE] == region).mean() > 0.9  # a scar in one region
    context, targets = lv.sites[:3], lv.sites[3:]

    baseline = FSBO(budget=25, seed=0, restarts=4, raw_samples=64)
    result = baseline.fit(lv.observe(truth, context), lv.solver)
    assert result.calls == 25 and result.sequences == 75
    assert int(np.argmax(result.params)) == region
    fitted, true = result.tissue.a >= 0.4, truth.label == LABEL_CORE
    assert 2 * (fitted & true).sum() / (fitted.sum() + true.sum()) > 0.5
    healthy, fitted_mse = _healthy_and_fitted_mse(lv, baseline, truth, targets)
    assert fitted_mse < 0.5 * healthy
