"""Episodic meta-training with exact resume, a NaN guard and atomic checkpoints.

One epoch draws one episode per training subject (docs/method.md, "Training objective"); episodes
depend only on ``(seed, epoch, subject)`` and every other random draw comes
from a generator saved in the checkpoint, so a run resumed from ``last.pt``
continues exactly as if it had never stopped.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from learner.config import LearnerConfig, config_from_mapping
from learner.data.episodes import Episode, EpisodeDataset
from learner.data.split import split_subjects
from learner.models.surrogate import PNS, build_model
from learner.runtime import set_threads, tune_allocator
from learner.store_view import StoreView
from learner.train.checkpoint import load_checkpoint, save_checkpoint
from learner.train.loss import LossTerms, episode_loss
from shared.errors import InputError

__all__ = ["TrainingDiverged", "TrainResult", "Trainer", "train", "load_model"]

#: Called once per training step: ``(episode, loss terms, gradient norm before clipping)``.
StepHook = Callable[[Episode, LossTerms, float], None]

#: Validation episodes use their own seed stream, disjoint from training epochs.
VALIDATION_EPOCH = 1_000_000


class TrainingDiverged(RuntimeError):
    """A non-finite loss or gradient; the last good checkpoint is kept."""


@dataclass
class TrainResult:
    """Where the run left its files and what it reached."""

    out: Path
    epochs_done: int
    history: list[dict] = field(default_factory=list)
    best_validation: float = math.inf
    stopped_early: bool = False


class Trainer:
    """Meta-trains a metaPNS (or PNS) model on the store named in ``config``."""

    def __init__(self, config: LearnerConfig, progress: bool = True) -> None:
        self.config, self.progress = config, progress
        self.out = Path(config.out)
        self.view = StoreView(config.data.store, cache_dir=self.out / "hierarchies")
        stored = self.view.stored_split if config.data.split.source == "store" else None  # one read per subject
        self.splits = split_subjects(self.view.subjects, self.view.mesh_of, config.data.split, stored)
        torch.manual_seed(config.train.seed)
        self.model: PNS = build_model(config.model, self.view.frames)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.train.lr)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, config.train.lr_halve_every, gamma=0.5)
        self.generator = torch.Generator().manual_seed(config.train.seed)
        self.epoch, self.history, self.best = 0, [], math.inf
        self.warm_start = self._warm_start(Path(config.train.init)) if config.train.init else None

    # -- checkpoints -------------------------------------------------------
    def state(self) -> dict:
        """Everything needed to resume (tensors and plain containers only)."""
        return {
            "kind": "model",
            "config": self.config.to_dict(),
            "frames": self.view.frames,
            "splits": self.splits,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "generator": self.generator.get_state(),
            "epoch": self.epoch,
            "history": self.history,
            "best_validation": self.best,
        }

    def _warm_start(self, path: Path) -> dict[str, list[str]]:
        """Copy the parameters of matching name and shape from a trained checkpoint (fine-tuning).

        The checkpoint must come from the same subject splits, or its test
        subjects could be in this run's training set. Returns the names
        copied and those left at their fresh initialisation.
        """
        ckpt = load_checkpoint(path, kind="model")
        if ckpt["splits"] != self.splits:
            raise InputError(f"train.init {path} was trained on other subject splits (data.split must match)")
        own = self.model.state_dict()
        taken = {k: v for k, v in ckpt["model"].items() if k in own and own[k].shape == v.shape}
        self.model.load_state_dict(taken, strict=False)
        return {"copied": sorted(taken), "fresh": sorted(set(own) - set(taken))}

    def resume(self, path: Path) -> None:
        """Continue from a checkpoint of the same configuration."""
        ckpt = load_checkpoint(path, kind="model")
        if _resumable(ckpt["config"]) != _resumable(self.config.to_dict()):
            raise InputError(f"{path} was written by a different configuration; use another `out` or --fresh")
        self.model.load_state_dict(ckpt["model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        self.generator.set_state(ckpt["generator"])
        self.epoch, self.history, self.best = ckpt["epoch"], list(ckpt["history"]), ckpt["best_validation"]

    def training_mean(self) -> float:
        """Mean potential of the first epoch's training episodes (context and targets, every node and frame)."""
        total, count = 0.0, 0
        for ep in self._episodes(self.splits["train"], 0):
            for u in (ep.context_u, ep.target_u):
                total, count = total + float(u.double().sum()), count + u.numel()
        return total / max(count, 1)

    # -- one epoch ---------------------------------------------------------
    def _episodes(self, subjects: list[str], epoch: int) -> DataLoader:
        spec, workers = self.config.data.episodes, self.config.data.workers
        ds = EpisodeDataset(self.config.data.store, subjects, spec, seed=self.config.train.seed, epoch=epoch)
        return DataLoader(ds, batch_size=None, num_workers=workers)

    def _kl_weight(self) -> float:
        ramp = self.config.train.kl_anneal_epochs
        return 1.0 if ramp <= 0 else min(1.0, (self.epoch + 1) / ramp)

    def _frames(self) -> torch.Tensor | None:
        k = self.config.train.loss_frames
        if k <= 0 or k >= self.view.frames:
            return None
        return torch.randperm(self.view.frames, generator=self.generator)[:k].sort().values

    def train_epoch(self, on_step: StepHook | None = None) -> dict[str, float]:
        """One episode per training subject; returns the mean loss terms and the gradient norms' median and maximum.

        ``on_step(episode, terms, grad_norm)`` is called after each backward pass
        and clipping, before the optimiser step (diagnostics:
        ``bench/training_stability.py``); ``grad_norm`` is the norm before clipping.
        """
        cfg, m = self.config.train, self.model
        m.train()
        sums: dict[str, float] = {}
        norms: list[float] = []
        loader = self._episodes(self.splits["train"], self.epoch)
        bar = tqdm(
            loader,
            total=len(self.splits["train"]),
            disable=not self.progress,
            leave=False,
            desc=f"epoch {self.epoch + 1}/{cfg.epochs}",
        )
        for n, ep in enumerate(bar, start=1):
            hier = self.view.hierarchy(ep.mesh_id, self.config.model.levels, self.config.model.coarsest)
            terms = episode_loss(
                m,
                ep,
                hier,
                cfg.lambda1,
                cfg.lambda2,
                self._kl_weight(),
                self._frames(),
                self.generator,
                cfg.posterior_targets or None,
            )
            self.optimizer.zero_grad(set_to_none=True)
            terms.total.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(m.parameters(), cfg.grad_clip)
            if not (torch.isfinite(terms.total) and torch.isfinite(grad_norm)):
                raise TrainingDiverged(
                    f"non-finite loss or gradient at epoch {self.epoch + 1}, subject {ep.subject_id}; "
                    f"the last good checkpoint is {self.out / 'last.pt'} (lower train.lr or train.grad_clip)"
                )
            if on_step is not None:
                on_step(ep, terms, float(grad_norm))
            self.optimizer.step()
            norms.append(float(grad_norm))
            for k, v in terms.as_floats().items():
                sums[k] = sums.get(k, 0.0) + v
            bar.set_postfix(loss=f"{sums['total'] / n:.4g}", mse=f"{sums['target_mse'] / n:.3g}")
        means = {k: v / max(len(self.splits["train"]), 1) for k, v in sums.items()}
        return {**means, "grad_norm_median": statistics.median(norms), "grad_norm_max": max(norms)}

    @torch.no_grad()
    def validate(self) -> float:
        """Mean target MSE on fixed validation episodes (c = mean of p(c | Y))."""
        subjects = self.splits["validation"] or self.splits["train"]
        self.model.eval()
        total, n = 0.0, 0
        ds = EpisodeDataset(
            self.config.data.store,
            subjects,
            self.config.data.episodes,
            seed=self.config.train.seed,
            epoch=VALIDATION_EPOCH,
        )
        for ep in ds:
            hier = self.view.hierarchy(ep.mesh_id, self.config.model.levels, self.config.model.coarsest)
            c = self.model.embed(ep.context_obs, ep.observed, hier).mu if self.model.conditioned else None
            pred = self.model.generate(ep.target_sites, hier, c)
            total, n = total + float(((pred - ep.target_u) ** 2).mean()), n + 1
        return total / max(n, 1)

    # -- the loop ----------------------------------------------------------
    def fit(self, on_epoch: Callable[[dict], None] | None = None, on_step: StepHook | None = None) -> TrainResult:
        """Train until ``train.epochs`` (or ``train.max_minutes``), checkpointing every epoch."""
        cfg = self.config.train
        tune_allocator()
        set_threads(cfg.threads)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "config.json").write_text(json.dumps(self.config.to_dict(), indent=2))
        if self.epoch == 0 and not self.history:
            if self.warm_start is not None:
                record = {"init": self.config.train.init, **self.warm_start}
                (self.out / "warm_start.json").write_text(json.dumps(record))
            if self.warm_start is None or "decoder.out.bias" in self.warm_start["fresh"]:
                self.model.set_output_mean(self.training_mean())
        start, stopped = time.perf_counter(), False
        while self.epoch < cfg.epochs:
            t0 = time.perf_counter()
            row = {"epoch": self.epoch + 1, "lr": self.optimizer.param_groups[0]["lr"], **self.train_epoch(on_step)}
            self.scheduler.step()
            self.epoch += 1
            row["seconds"] = time.perf_counter() - t0
            stopped = cfg.max_minutes > 0 and time.perf_counter() - start > 60 * cfg.max_minutes
            if self.epoch % cfg.validate_every == 0 or self.epoch == cfg.epochs or stopped:
                row["val_target_mse"] = self.validate()
                if row["val_target_mse"] < self.best:
                    self.best = row["val_target_mse"]
                    save_checkpoint(self.out / "best.pt", self.state())
            self.history.append(row)
            save_checkpoint(self.out / "last.pt", self.state())
            self._log(row)
            if on_epoch is not None:
                on_epoch(row)
            if stopped:
                break
        if not (self.out / "best.pt").exists():
            save_checkpoint(self.out / "best.pt", self.state())
        return TrainResult(self.out, self.epoch, self.history, self.best, stopped)

    def _log(self, row: dict) -> None:
        path = self.out / "log.csv"
        keys = [
            "epoch",
            "lr",
            "total",
            "target_mse",
            "context_mse",
            "kl_posterior",
            "kl_prior",
            "grad_norm_median",
            "grad_norm_max",
            "val_target_mse",
            "seconds",
        ]
        new = not path.exists()
        with path.open("a", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow(row)
        with (self.out / "log.jsonl").open("a") as fh:
            fh.write(json.dumps(row) + "\n")


def _resumable(config: dict) -> dict:
    """The configuration without what a resumed run may change (its length and time budget).

    Keys added to the configuration since the checkpoint was written take their defaults.
    """
    config = config_from_mapping(config).to_dict()
    train = {k: v for k, v in config["train"].items() if k not in ("epochs", "max_minutes")}
    return {**config, "train": train}


def train(
    config: LearnerConfig, fresh: bool = False, progress: bool = True, on_epoch: Callable[[dict], None] | None = None
) -> TrainResult:
    """Train per ``config``; resumes from ``<out>/last.pt`` unless ``fresh``."""
    trainer = Trainer(config, progress)
    last = Path(config.out) / "last.pt"
    if fresh:
        for name in ("last.pt", "best.pt", "log.csv", "log.jsonl"):
            (Path(config.out) / name).unlink(missing_ok=True)
    elif last.exists():
        trainer.resume(last)
    return trainer.fit(on_epoch)


def load_model(path: str | Path) -> tuple[PNS, LearnerConfig, dict]:
    """A trained model (eval mode), its config and the checkpoint dict."""
    ckpt = load_checkpoint(path, kind="model")
    config = config_from_mapping(ckpt["config"])
    model = build_model(config.model, ckpt["frames"])
    model.load_state_dict(ckpt["model"])
    return model.eval(), config, ckpt
