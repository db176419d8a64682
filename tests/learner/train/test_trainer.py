"""Training: every seed learns, a tiny model overfits one subject, resume is exact, NaN stops
cleanly, checkpoints are safe."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.data.episodes import EpisodeDataset, load_episode
from learner.train.trainer import VALIDATION_EPOCH, StepCost, Trainer, TrainingDiverged, load_model, train
from shared.errors import ConfigError, InputError


def _episode_mse(model, trainer, ep) -> float:
    hier = trainer.view.hierarchy(ep.mesh_id, trainer.config.model.levels, trainer.config.model.coarsest)
    with torch.no_grad():
        c = model.embed(ep.context_obs, ep.observed, hier).mu
        pred = model.generate(torch.cat([ep.context_sites, ep.target_sites]), hier, c)
    return float(((pred - torch.cat([ep.context_u, ep.target_u])) ** 2).mean())


def _frame_mean_mse(trainer: Trainer) -> float:
    """Validation target MSE of the per-frame mean of the training data: a predictor that ignores site and context."""
    frame_mean = torch.from_numpy(trainer.view.frame_means(trainer.splits["train"])).float()[None, :, None]
    episodes = EpisodeDataset(
        trainer.config.data.store,
        trainer.splits["validation"],
        trainer.config.data.episodes,
        seed=trainer.config.train.seed,
        epoch=VALIDATION_EPOCH,
    )
    return float(np.mean([float(((ep.target_u - frame_mean) ** 2).mean()) for ep in episodes]))


#: The runs of :func:`test_every_seed_learns_past_the_input_ignoring_level`: model keys, train keys and seeds.
RUNS = {
    "default": ({}, {}, (0, 1, 2)),
    "shipped-gate": ({"capture_gate": True, "capture_evidence": True}, {"gate_loss": 0.1}, (0,)),
}


def test_every_seed_learns_past_the_input_ignoring_level(tiny_store, tiny_config, tmp_path):
    """Three seeds, 60 epochs of 4 steps: no loss spike, and each gets well below the per-frame mean predictor.

    In units of that predictor's validation error, the best validation stays
    under 0.4 and the last four validations under 0.5 on average (one
    validation subject of 4 targets is noisy; seeds 0-2 reach 0.18, 0.17 and
    0.20). The shipped configs' capture gate (``model.capture_gate``,
    ``capture_evidence`` and ``train.gate_loss``) is held to the same bounds
    on seed 0 (0.21). The four runs train at once, on one thread each.
    """
    configs = {
        (name, seed): tiny_config(
            tiny_store,
            tmp_path / f"{name}-seed{seed}",
            model=model,
            epochs=60,
            lr=3e-3,
            seed=seed,
            validate_every=5,
            threads=1,  # one core each: the runs share the machine
            **train,
        )
        for name, (model, train, seeds) in RUNS.items()
        for seed in seeds
    }
    # the runs after the first train in their own processes, beside this one (the suite's machine has 2 cores)
    first, *rest = configs
    others = {run: _fit_in_a_process(configs[run]) for run in rest}
    try:
        for run, cfg in configs.items():
            trainer = Trainer(cfg, progress=False)
            ignoring = _frame_mean_mse(trainer)
            if run == first:
                history = trainer.fit().history
            else:
                assert others[run].wait(timeout=600) == 0, (run, others[run].stderr.read())
                history = [json.loads(line) for line in (Path(cfg.out) / "log.jsonl").read_text().splitlines()]
            val = [row["val_target_mse"] / ignoring for row in history if "val_target_mse" in row]
            train_mse = [row["target_mse"] for row in history]
            assert min(val) < 0.4, (run, val)
            assert np.mean(val[-4:]) < 0.5, (run, val)  # not back at the input-ignoring level late in training
            assert max(train_mse[1:]) < 2 * train_mse[0], (run, train_mse)  # no spike above the first epoch
    finally:
        for process in others.values():  # none left running after a failure
            if process.poll() is None:
                process.kill()
                process.wait()


def _fit_in_a_process(cfg) -> subprocess.Popen:
    """``Trainer(cfg).fit()`` in a fresh Python process (its rows land in ``<out>/log.jsonl``)."""
    script = (
        "import json, sys; from learner.config import config_from_mapping; from learner.train.trainer import Trainer; "
        "Trainer(config_from_mapping(json.loads(sys.argv[1])), progress=False).fit()"
    )
    return subprocess.Popen(
        [sys.executable, "-c", script, json.dumps(cfg.to_dict())], stderr=subprocess.PIPE, text=True
    )


def test_a_fresh_model_starts_as_the_mean_predictor(tiny_store, tiny_config, tmp_path):
    trainer = Trainer(tiny_config(tiny_store, tmp_path / "mean"), progress=False)
    mean = trainer.training_mean()
    episodes = list(trainer._episodes(trainer.splits["train"], 0))
    values = torch.cat([torch.cat([ep.context_u.flatten(), ep.target_u.flatten()]) for ep in episodes]).double()
    assert mean == pytest.approx(float(values.mean()), rel=1e-9)
    trainer.model.set_output_mean(mean)
    hier = trainer.view.hierarchy(episodes[0].mesh_id, trainer.config.model.levels, trainer.config.model.coarsest)
    with torch.no_grad():
        c = trainer.model.embed(episodes[0].context_obs, episodes[0].observed, hier).mu
        pred = trainer.model.generate(episodes[0].target_sites, hier, c)
    torch.testing.assert_close(pred, torch.full_like(pred, mean))


def test_tiny_model_overfits_one_subject(tiny_store, tiny_config, tmp_path):
    cfg = tiny_config(tiny_store, tmp_path / "run", epochs=150, lr=3e-3, lr_halve_every=100, validate_every=1000)
    trainer = Trainer(cfg, progress=False)
    trainer.splits = {"train": ["lv-scar-apex"], "validation": [], "test": []}
    ep = load_episode(tiny_store, "lv-scar-apex", [0, 1], list(range(2, 12)), "surface")
    before = _episode_mse(trainer.model, trainer, ep)
    trainer.fit()
    after = _episode_mse(trainer.model, trainer, ep)
    assert after < before / 10, (before, after)


def test_resume_continues_exactly(tiny_store, tiny_config, tmp_path):
    straight = train(tiny_config(tiny_store, tmp_path / "a", epochs=2), progress=False)
    train(tiny_config(tiny_store, tmp_path / "b", epochs=1), progress=False)
    resumed = train(tiny_config(tiny_store, tmp_path / "b", epochs=2), progress=False)
    keys = ("total", "target_mse", "context_mse", "kl_posterior", "kl_prior", "val_target_mse")
    assert [[r[k] for k in keys] for r in straight.history] == [[r[k] for k in keys] for r in resumed.history]
    a, b = load_checkpoint(tmp_path / "a" / "last.pt"), load_checkpoint(tmp_path / "b" / "last.pt")
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])


def test_resume_refuses_another_configuration(tiny_store, tiny_config, tmp_path):
    train(tiny_config(tiny_store, tmp_path / "r", epochs=1), progress=False)
    with pytest.raises(InputError, match="different configuration"):
        train(tiny_config(tiny_store, tmp_path / "r", epochs=1, lr=5e-4), progress=False)


def test_resume_fills_keys_added_since_the_checkpoint(tiny_store, tiny_config, tmp_path):
    train(tiny_config(tiny_store, tmp_path / "r", epochs=1), progress=False)
    ckpt = load_checkpoint(tmp_path / "r" / "last.pt")
    del ckpt["config"]["model"]["latent_norm"]  # a checkpoint written before the key existed (default: True)
    save_checkpoint(tmp_path / "r" / "last.pt", {k: v for k, v in ckpt.items() if k != "format"})
    resumed = train(tiny_config(tiny_store, tmp_path / "r", epochs=2), progress=False)
    assert [r["epoch"] for r in resumed.history] == [1, 2]


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tiny_store, tiny_config, tmp_path, monkeypatch):
    cfg = tiny_config(tiny_store, tmp_path / "nan", epochs=1)
    train(cfg, progress=False)
    good = load_checkpoint(tmp_path / "nan" / "last.pt")
    import learner.train.loss as loss_module

    real = loss_module.episode_loss

    def poisoned(*args, **kw):
        terms = real(*args, **kw)
        terms.total = terms.total * float("nan")
        return terms

    monkeypatch.setattr(loss_module, "episode_loss", poisoned)
    with pytest.raises(
        TrainingDiverged, match=f"non-finite.*the last good checkpoint is {tmp_path / 'nan' / 'last.pt'}"
    ):
        train(dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, epochs=2)), progress=False)
    kept = load_checkpoint(tmp_path / "nan" / "last.pt")
    assert kept["epoch"] == good["epoch"] == 1
    assert all(torch.equal(kept["model"][k], good["model"][k]) for k in good["model"])
    with pytest.raises(TrainingDiverged, match=f"non-finite.*no checkpoint was written yet in {tmp_path / 'fresh'}"):
        train(tiny_config(tiny_store, tmp_path / "fresh", epochs=1), progress=False)


def test_a_time_budget_counts_the_next_epoch_and_the_closing_validation():
    cost = StepCost(epoch_s=10.0)  # no validation measured yet: taken as long as an epoch
    assert not cost.overruns(0.0, 1e9, validating=True)  # no budget
    assert not cost.overruns(60.0, 40.0, validating=False)  # 40 + 10 + 10 = 60
    assert cost.overruns(60.0, 40.0, validating=True)  # a validation due now: 70
    cost.validation_s = 2.0
    assert not cost.overruns(60.0, 40.0, validating=True) and cost.overruns(60.0, 47.0, validating=True)


def test_a_budget_shorter_than_an_epoch_stops_after_one_validated_epoch(tiny_store, tiny_config, tmp_path):
    result = train(tiny_config(tiny_store, tmp_path / "run", epochs=5, validate_every=5, max_minutes=1e-6))
    assert result.stopped_early and result.epochs_done == 1 and "val_target_mse" in result.history[-1]
    assert not train(tiny_config(tiny_store, tmp_path / "all", epochs=1, max_minutes=1e-6)).stopped_early


def test_checkpoint_loads_with_weights_only_and_rebuilds_the_model(tiny_store, tiny_config, tmp_path):
    train(tiny_config(tiny_store, tmp_path / "w", epochs=1), progress=False)
    raw = torch.load(tmp_path / "w" / "best.pt", weights_only=True)
    assert raw["kind"] == "model" and raw["frames"] == 12
    model, config, _ = load_model(tmp_path / "w" / "best.pt")
    assert config.model.kind == "metapns" and not model.training
    header = (tmp_path / "w" / "log.csv").read_text().splitlines()[0]
    assert header.startswith("epoch,") and "grad_norm_median,grad_norm_max" in header


def test_bad_configs_are_refused(tiny_store, tiny_config, tmp_path):
    from learner.config import config_from_mapping

    with pytest.raises(InputError, match="context size must be >= 1"):
        config_from_mapping({"data": {"store": str(tiny_store), "episodes": {"context": [0, 2]}}})
    with pytest.raises(ConfigError, match="unknown key"):
        config_from_mapping({"data": {"store": str(tiny_store)}, "train": {"epoch": 3}})
    with pytest.raises(ConfigError, match="data.store is required"):
        config_from_mapping({})
    with pytest.raises(ConfigError, match="levels"):
        config_from_mapping({"data": {"store": "x"}, "model": {"levels": 3}})
    with pytest.raises(ConfigError, match="train.c_from: 'targets' is not one of"):
        config_from_mapping({"data": {"store": "x"}, "train": {"c_from": "targets"}})
    with pytest.raises(ConfigError, match="train.lr: expected a finite number, got nan"):
        config_from_mapping({"data": {"store": "x"}, "train": {"lr": float("nan")}})
    with pytest.raises(ConfigError, match="data.episodes.targets must be >= 1"):
        config_from_mapping({"data": {"store": "x", "episodes": {"targets": 0}}})
    with pytest.raises(InputError):
        Trainer(tiny_config(tmp_path / "missing.zarr", tmp_path / "o"), progress=False)


def test_warm_start_copies_matching_parameters_and_refuses_other_splits(tiny_store, tiny_config, tmp_path):
    train(tiny_config(tiny_store, tmp_path / "pre", epochs=1), progress=False)
    pre = load_checkpoint(tmp_path / "pre" / "last.pt")["model"]
    cfg = tiny_config(tiny_store, tmp_path / "fine", epochs=1, init=str(tmp_path / "pre" / "last.pt"))
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, context_stride=3))  # 4 of 12 frames encoded
    trainer = Trainer(cfg, progress=False)
    own = trainer.model.state_dict()
    assert trainer.warm_start["fresh"] == ["context_encoder.compress_time.weight"]  # (1, 4) here, (1, 12) before
    assert all(torch.equal(own[k], pre[k]) for k in trainer.warm_start["copied"])
    assert len(trainer.warm_start["copied"]) == len(own) - 1
    trainer.fit()
    assert (tmp_path / "fine" / "warm_start.json").exists()

    other = tiny_config(tiny_store, tmp_path / "other", init=str(tmp_path / "pre" / "last.pt"))
    other = dataclasses.replace(
        other, data=dataclasses.replace(other.data, split=dataclasses.replace(other.data.split, seed=1))
    )
    with pytest.raises(InputError, match="other subject splits"):
        Trainer(other, progress=False)

    # a maps encoder starts as the context encoder it lacks, and trains alone on maps read up to each upstroke
    maps = tiny_config(
        tiny_store,
        tmp_path / "maps",
        epochs=1,
        init=str(tmp_path / "pre" / "last.pt"),
        trainable=["maps_encoder"],
        c_from="context",
        model={"maps_encoder": True},
    )
    episodes = dataclasses.replace(maps.data.episodes, activation_maps=1.0)
    maps = dataclasses.replace(maps, data=dataclasses.replace(maps.data, episodes=episodes))
    trainer = Trainer(maps, progress=False)
    assert trainer.warm_start["fresh"] == []
    start = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    assert all(torch.equal(v, pre[k.replace("maps_encoder.", "context_encoder.")]) for k, v in start.items())
    trainer.fit()
    end = trainer.model.state_dict()
    changed = {k for k in end if not torch.equal(end[k], start[k])}
    assert changed and all(k.startswith("maps_encoder.") for k in changed)
