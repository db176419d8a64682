"""Personalising from the ECG: lead fields, episodes recorded as ECGs, the ECG encoder trained beside a frozen
model, ECG observation files, and the patient's path from `simgen simulate --observe ecg` to predicted ECGs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from learner.cli import app as learner_app
from learner.data.episodes import load_episode, subject_lead_fields
from learner.ecg import LeadField, resample_ecg
from learner.graph.hierarchy import hierarchy_for_mesh
from learner.models.surrogate import build_model
from learner.observations import observations_from_file
from learner.personalized import personalize
from learner.refine import Refinement, ecg_leads, fit_context
from learner.train.trainer import Trainer
from shared.ecg import LEADS, PseudoECG, leads, standard_electrodes
from shared.errors import InputError
from shared.reader import read_mesh, read_tissue
from simgen.cli import app as simgen_app
from simgen.meshes.catalog import get_mesh


def test_a_lead_field_gives_the_pseudo_ecg_and_a_density_of_unit_scale():
    mesh = get_mesh("lv", 500)
    field = LeadField.of_mesh(mesh)
    u = np.random.default_rng(0).random((2, 5, mesh.n_nodes))
    expected = leads(PseudoECG.assemble(mesh, standard_electrodes(mesh)).potentials(u), standard_electrodes(mesh))
    found = field.ecg(torch.as_tensor(u, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(found, expected, rtol=1e-4, atol=1e-5 * np.abs(expected).max())
    np.testing.assert_allclose(field.density.abs().amax(dim=0).numpy(), 1.0, rtol=1e-6)


def test_an_episode_recorded_as_ecgs_holds_its_contexts_ecgs_with_their_noise(tiny_store):
    subject = "lv-scar-apex"
    clean = load_episode(tiny_store, subject, [0, 3], [5], ecg_noise=0.0)
    truth, healthy = subject_lead_fields(str(tiny_store), subject, clean.mesh_id)
    mesh = read_mesh(tiny_store, clean.mesh_id)
    scarred = LeadField.of_mesh(mesh, scale=read_tissue(tiny_store, subject).D)
    np.testing.assert_allclose(clean.context_ecg.numpy(), scarred.ecg(clean.context_u).numpy(), rtol=1e-5, atol=1e-6)
    assert not torch.allclose(truth.matrix, healthy.matrix)  # the scar weighs the subject's ECG, not the encoder's
    torch.testing.assert_close(clean.lead_matrix, healthy.matrix)
    noisy = load_episode(tiny_store, subject, [0, 3], [5], rng=np.random.default_rng(1), ecg_noise=0.05)
    spread = float((noisy.context_ecg - clean.context_ecg).std())
    assert spread == pytest.approx(0.05 * float(clean.context_ecg.abs().max()), rel=0.1)


def _ecg_config(tiny_config, store, out, init=""):
    cfg = tiny_config(
        store,
        out,
        model={"ecg_encoder": True},
        init=str(init),
        trainable=["ecg_encoder"] if init else [],
        reconstruction=False,
        c_from="context",
        lambda1=1.0,
    )
    return replace(cfg, data=replace(cfg.data, episodes=replace(cfg.data.episodes, ecg=1.0)))


@pytest.fixture(scope="module")
def ecg_run(tiny_store, tiny_config, tmp_path_factory):
    """A tiny model trained 1 epoch, then its ECG encoder trained 2 epochs beside it, frozen; the weights before."""
    folder = tmp_path_factory.mktemp("ecg")
    base = Trainer(tiny_config(tiny_store, folder / "base", epochs=1), progress=False)
    base.fit()
    trainer = Trainer(_ecg_config(tiny_config, tiny_store, folder / "run", base.out / "best.pt"), progress=False)
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    result = trainer.fit()
    return trainer, before, result


def test_only_the_ecg_encoder_learns_and_the_frozen_model_is_unchanged(ecg_run):
    trainer, before, result = ecg_run
    after = trainer.model.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and all(k.startswith("ecg_encoder.") for k in changed)
    assert all(np.isfinite(row["total"]) for row in result.history if "total" in row)
    assert result.best_validation < np.inf


def test_evaluate_reads_each_context_set_as_ecgs(ecg_run, tiny_store, tmp_path):
    trainer, _, _ = ecg_run
    args = ["evaluate", str(trainer.out / "best.pt"), str(tiny_store), "--sets", "1", "--max-targets", "2"]
    result = CliRunner().invoke(learner_app, [*args, "--observe", "ecg", "--out", str(tmp_path), "--refine-steps", "2"])
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "evaluation.json").read_text())
    assert np.isfinite(report["overall"]["target"]["cc_spatial"]["mean"])


def test_refining_c_on_ecgs_lowers_their_misfit_through_the_lead_field():
    """The shipped model personalised on the ECGs of three pacings of a scarred LV: a few steps on ``c`` fit the
    ECGs of its predictions (through the mesh's lead field) better than the encoder's mean."""
    from learner.pretrained import load
    from simgen.solver.simulate import Simulator
    from simgen.tissue import default_settings, tissue_fields

    mesh = get_mesh("lv", 1000)
    sites = np.array([10, 400, 800])
    scar = next(spec for spec in default_settings() if spec.name == "scar-septal-basal")
    u = Simulator(mesh, tissue_fields(mesh, scar)).run(sites, threads=2).u
    model = load("anatomies")
    hierarchy = hierarchy_for_mesh(mesh, 5, 40, None, 500)
    field = LeadField.of_mesh(mesh)
    ecg = field.ecg(torch.as_tensor(u, dtype=torch.float32))[:, :, : model.frames]
    with torch.no_grad():
        post = model.embed_ecg(ecg, field, torch.as_tensor(sites), hierarchy)
    scale = float(ecg.abs().max())
    record, fit = ecg_leads(field, scale), (torch.as_tensor(sites), ecg / scale)
    mu, var = post.mu, post.logvar.exp()
    c, history, _ = fit_context(model, mu, var, fit, hierarchy, None, record, Refinement(steps=5), 5)
    assert len(history) == 6 and history[-1] < history[0]
    with torch.no_grad():
        misfit = [float((record(model.generate(fit[0], hierarchy, x)) - fit[1]).pow(2).mean()) for x in (mu, c)]
    assert misfit[1] < 0.9 * misfit[0]


def test_the_ecg_embedding_does_not_depend_on_the_order_of_the_recordings(tiny_store, tiny_config, tmp_path):
    cfg = _ecg_config(tiny_config, tiny_store, tmp_path)
    model = build_model(cfg.model, 12).eval()
    mesh = get_mesh("lv", 500)
    hierarchy = hierarchy_for_mesh(mesh, cfg.model.levels, cfg.model.coarsest)
    field = LeadField.of_mesh(mesh)
    ecg = torch.randn(3, len(LEADS), 12)
    sites = torch.tensor([4, 100, 250])
    with torch.no_grad():
        first = model.embed_ecg(ecg, field, sites, hierarchy)
        swapped = model.embed_ecg(ecg[[2, 0, 1]], field, sites[[2, 0, 1]], hierarchy)
        moved = model.embed_ecg(ecg, field, torch.tensor([4, 100, 300]), hierarchy)
    torch.testing.assert_close(first.mu, swapped.mu, rtol=1e-5, atol=1e-6)
    assert not torch.allclose(first.mu, moved.mu)  # where the pacing was is part of what an ECG says


def test_ecgs_are_resampled_and_their_leads_put_in_order():
    times = np.array([0.0, 10.0, 20.0, 30.0])
    ecg = np.broadcast_to(np.arange(12.0)[None, :, None] + times / 10.0, (2, 12, 4)).copy()
    names = list(LEADS[::-1])
    found = resample_ecg(ecg[:, ::-1], times, np.array([5.0, 25.0]), names)
    np.testing.assert_allclose(found[0, :, 0], np.arange(12.0) + 0.5)
    np.testing.assert_allclose(found[1, :, 1], np.arange(12.0) + 2.5)
    np.testing.assert_allclose(resample_ecg(ecg, times, np.array([10.0, 40.0]))[:, :, 1], ecg[:, :, -1])
    with pytest.raises(InputError, match=r"ends at 30.0 ms; the model needs it up to 41.0 ms"):
        resample_ecg(ecg, times, np.array([10.0, 41.0]))
    with pytest.raises(InputError, match=r"missing \['V6'\]"):
        resample_ecg(ecg, times, times, [*LEADS[:11], "V7"])
    with pytest.raises(InputError, match="12 leads"):
        resample_ecg(ecg[:, :8], times, times)


def test_the_patients_path_from_a_simulated_ecg_to_predicted_ecgs(ecg_run, tmp_path):
    """`simgen simulate --observe ecg` writes an observation file that personalize reads, and the predictions come
    with their ECGs through the mesh's lead field."""
    trainer, _, _ = ecg_run
    mesh_file = tmp_path / "heart.vtu"
    runner = CliRunner()
    made = runner.invoke(simgen_app, ["mesh", str(mesh_file), "--mesh", "lv", "--nodes", "500"])
    assert made.exit_code == 0, made.output
    rec = runner.invoke(
        simgen_app,
        ["simulate", str(tmp_path / "rec"), "--mesh", str(mesh_file), "--sites", "10,200", "--observe", "ecg"]
        + ["--noise", "0.01"],
    )
    assert rec.exit_code == 0, rec.output
    obs = observations_from_file(tmp_path / "rec" / "observations.npz")
    assert obs.ecg.shape[:2] == (2, 12) and obs.electrodes is not None and not obs.observed.any()
    heart = personalize(trainer.out / "best.pt", obs, tmp_path / "heart.pt")
    prediction = heart.predict([50, 300])
    field = LeadField.of_mesh(obs.mesh, obs.electrodes)
    np.testing.assert_allclose(prediction.ecg, field.ecg(torch.as_tensor(prediction.u)).numpy(), rtol=1e-4, atol=1e-6)
    out = tmp_path / "prediction.npz"
    done = runner.invoke(learner_app, ["predict", str(tmp_path / "heart.pt"), "--sites", "50", "--out", str(out)])
    assert done.exit_code == 0, done.output
    with np.load(out) as saved:
        assert saved["ecg_mv"].shape == (1, 12, len(saved["times_ms"])) and list(saved["leads"]) == list(LEADS)


def test_ecg_files_that_cannot_be_read_are_refused_naming_the_array(tmp_path):
    mesh = get_mesh("lv", 500)
    base = {"points": mesh.points, "cells": mesh.cells, "sites": np.array([3]), "ecg_mv": np.zeros((1, 12, 50))}
    path = tmp_path / "obs.npz"
    np.savez(path, **base)
    with pytest.raises(InputError, match="lacks array.*ecg_times_ms"):
        observations_from_file(path)
    np.savez(path, **base, ecg_times_ms=np.arange(50.0), leads=np.array([*LEADS[:11], "X"]))
    with pytest.raises(InputError, match=r"obs.npz: leads .* \(missing \['V6'\]\)"):
        observations_from_file(path)
    np.savez(path, **base, ecg_times_ms=np.arange(50.0), electrodes=np.array(["RA"]))
    with pytest.raises(InputError, match="electrode_xyz_mm"):
        observations_from_file(path)
