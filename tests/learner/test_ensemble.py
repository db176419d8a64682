"""Ensembles of surrogates: the averaged prediction, what members must share, evaluation through the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.cli import app
from learner.config import ModelConfig
from learner.data.episodes import load_episode
from learner.evaluate import EnsembleMethod, NeuralMethod, evaluate, load_method
from learner.models.surrogate import MetaPNS
from learner.refine import Refinement
from learner.store_view import StoreView
from shared.errors import InputError

CONFIG = ModelConfig(channels=(4, 8), hidden=16, latent=8, levels=3, coarsest=10, coarse_blocks=1)
runner = CliRunner()


@pytest.fixture(scope="module")
def fitted(tiny_store, trained_like):
    view = StoreView(tiny_store)
    hier = view.hierarchy("lv", CONFIG.levels, CONFIG.coarsest)
    episode = load_episode(tiny_store, "lv-scar-apex", [0, 5], [1, 2, 3], "surface")
    members = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        members.append(NeuralMethod(trained_like(MetaPNS(CONFIG, view.frames).eval()), f"m{seed}"))
    return view, hier, episode, members


@pytest.mark.parametrize("refine", [Refinement(), Refinement(steps=3)])
def test_the_ensemble_predicts_the_mean_of_its_members(fitted, refine):
    view, hier, ep, members = fitted
    members = [NeuralMethod(m.model, m.name, refine=refine) for m in members]
    sites = torch.cat([ep.context_sites, ep.target_sites])
    alone = []
    for m in members:
        m.fit(ep, view.mesh("lv"), hier)
        alone.append(m.predict(sites))
    assert not np.allclose(alone[0], alone[1])  # two different models, so the mean is not trivially one of them
    ensemble = EnsembleMethod(members, "both")
    cost = ensemble.fit(ep, view.mesh("lv"), hier)
    assert cost["fit_s"] >= 0
    np.testing.assert_allclose(ensemble.predict(sites), (alone[0] + alone[1]) / 2, rtol=1e-6, atol=1e-7)


def test_an_ensemble_of_one_model_twice_is_that_model(fitted):
    view, hier, ep, members = fitted
    twice = EnsembleMethod([members[0], NeuralMethod(members[0].model, "again")], "twice")
    twice.fit(ep, view.mesh("lv"), hier)
    members[0].fit(ep, view.mesh("lv"), hier)
    np.testing.assert_allclose(twice.predict(ep.target_sites), members[0].predict(ep.target_sites), rtol=1e-6)


def test_an_ensemble_needs_two_members(fitted):
    with pytest.raises(InputError, match="at least 2 members"):
        EnsembleMethod(fitted[3][:1], "one")


@pytest.fixture(scope="module")
def two_runs(tiny_store, tiny_toml, tmp_path_factory):
    """Two tiny trained runs of one config and seeds 0 and 1: the same splits, other weights."""
    folder = tmp_path_factory.mktemp("ensemble")
    cfg = folder / "train.toml"
    cfg.write_text(tiny_toml(tiny_store, train="epochs = 1"))
    for seed in (0, 1):
        args = ["train", str(cfg), "--seed", str(seed), "--out", str(folder / f"seed{seed}")]
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
    return folder / "seed0" / "best.pt", folder / "seed1" / "best.pt"


def test_evaluate_averages_the_members_on_the_same_draws(two_runs, tiny_store, tmp_path):
    """Through the CLI: ``--ensemble`` scores the averaged prediction on the context sets and targets of one model."""
    reports = {}
    for name, extra in (("alone", []), ("ensemble", ["--ensemble", str(two_runs[1])])):
        out = tmp_path / name
        args = ["evaluate", str(two_runs[0]), str(tiny_store), "--sets", "1", "--max-targets", "2", "--out", str(out)]
        result = runner.invoke(app, [*args, *extra])
        assert result.exit_code == 0, result.output
        reports[name] = json.loads((out / "evaluation.json").read_text())
    assert reports["ensemble"]["model"] == "ensemble of 2 metapns"
    keys = lambda rows: [(r["subject"], r["set"], r["site"], r["role"]) for r in rows]  # noqa: E731
    assert keys(reports["ensemble"]["rows"]) == keys(reports["alone"]["rows"])
    assert reports["ensemble"]["rows"] != reports["alone"]["rows"]


def test_members_must_agree_on_the_mesh_hierarchy(two_runs, tmp_path):
    ckpt = load_checkpoint(two_runs[1], kind="model")
    ckpt["config"]["model"]["levels"] += 1
    other = tmp_path / "other-levels.pt"
    save_checkpoint(other, ckpt)
    with pytest.raises(InputError, match="model.levels"):
        load_method([two_runs[0], other])


def test_members_must_share_the_evaluated_split(two_runs, tiny_store, tmp_path):
    ckpt = load_checkpoint(two_runs[1], kind="model")
    ckpt["splits"]["test"], ckpt["splits"]["train"] = ckpt["splits"]["train"][:1], ckpt["splits"]["test"]
    other = tmp_path / "other-split.pt"
    save_checkpoint(other, ckpt)
    with pytest.raises(InputError, match="another 'test' split"):
        evaluate([two_runs[0], other], tiny_store)
