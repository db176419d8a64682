"""VAE-BO recovers a library-like scar it was not trained on and predicts targets better than healthy."""

from __future__ import annotations

import numpy as np

from learner.baselines import VAEBO, fields_from_excitability, scar_library


def test_recovers_a_held_out_library_like_scar_and_beats_healthy_on_targets(lv):
    a = scar_library(lv.mesh, count=10, seed=123)[2].astype(np.float64)  # not in the training library (seed 0)
    truth = fields_from_excitability(a)
    context, targets = lv.sites[:3], lv.sites[3:]

    baseline = VAEBO(latent=3, budget=30, seed=0, restarts=4, raw_samples=64)
    result = baseline.fit(lv.observe(truth, context), lv.solver)
    assert result.calls == 30 and result.params.shape == (3,) and np.all(np.abs(result.params) <= 3.0)
    assert result.setup_seconds > 0  # the library and the VAE were built for this mesh
    fitted, true = result.tissue.a >= 0.4, a >= 0.4
    assert 2 * (fitted & true).sum() / (fitted.sum() + true.sum()) > 0.5

    u_true = lv.simulator.simulate(lv.mesh, truth, targets, lv.solver)
    u_healthy = lv.simulator.simulate(
        lv.mesh, fields_from_excitability(np.full(lv.mesh.n_nodes, 0.15)), targets, lv.solver
    )
    assert np.mean((baseline.predict(targets) - u_true) ** 2) < 0.25 * np.mean((u_healthy - u_true) ** 2)


def test_builds_the_vae_once_per_mesh_and_refits_identically(lv, counting):
    context = lv.observe(fields_from_excitability(np.full(lv.mesh.n_nodes, 0.15)), lv.sites[:1])
    baseline = VAEBO(latent=2, library_size=20, epochs=5, budget=6, restarts=2, raw_samples=32, simulator=counting)
    assert repr(baseline) == "VAEBO(latent=2, library_size=20, budget=6, seed=0)"
    first = baseline.fit(context, lv.solver)
    vae = baseline.vae
    second = baseline.fit(context, lv.solver)
    assert baseline.vae is vae and counting.calls == 12
    np.testing.assert_array_equal(first.history, second.history)
    np.testing.assert_array_equal(first.tissue.a, vae.decode(first.params))
