"""Episodic meta-training with exact resume, a NaN guard and atomic checkpoints, on one process or several.

One epoch draws one episode per training subject (docs/method.md, "Training objective"). An episode
and every random draw of its loss (the decoded frame subset, the posterior samples) depend only on
``(seed, epoch, subject)``, so a run resumed from ``last.pt`` continues exactly as if it had never
stopped, and no draw depends on which process trains the episode. With several processes
(:mod:`learner.train.distributed`) each trains its share of an epoch's steps under
``DistributedDataParallel``; rank 0 writes the checkpoints and logs.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from learner.activation_maps import ApTemplate, template_from_store
from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.config import LearnerConfig, config_from_mapping
from learner.data.episodes import Episode, EpisodeDataset
from learner.data.split import split_subjects
from learner.graph.hierarchy import MeshHierarchy
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import PNS, build_model
from learner.runtime import autocast, on_device, resolve_device, set_threads, tune_allocator
from learner.store_view import StoreView
from learner.train.distributed import SINGLE_PROCESS, World, kill_point, process_group
from learner.train.loss import EpisodeObjective, LossTerms
from shared.errors import InputError

__all__ = ["TrainingDiverged", "TrainResult", "Trainer", "train", "load_model"]

#: Called once per training step: ``(episode, loss terms, gradient norm before clipping)``.
StepHook = Callable[[Episode, LossTerms, float], None]

#: Validation episodes use their own seed stream, disjoint from training epochs.
VALIDATION_EPOCH = 1_000_000


@dataclass
class StepCost:
    """The longest training epoch and validation pass measured so far, in seconds, for a time budget."""

    epoch_s: float = 0.0
    validation_s: float | None = None  # None: no validation measured yet, taken to cost an epoch

    def overruns(self, budget_s: float, elapsed_s: float, validating: bool) -> bool:
        """Whether the validation due now, one more epoch and the validation that ends the run pass ``budget_s``.

        A budget of 0 is none.
        """
        validation = self.epoch_s if self.validation_s is None else self.validation_s
        return budget_s > 0 and elapsed_s + validation * validating + self.epoch_s + validation > budget_s


def trainable_parameters(model: nn.Module, parts: tuple[str, ...]) -> list[nn.Parameter]:
    """The parameters of ``model``'s top-level modules named in ``parts`` (all when empty); the rest are frozen."""
    named = dict(model.named_children())
    unknown = [p for p in parts if p not in named]
    if unknown:
        raise InputError(f"train.trainable names {unknown}, which the model lacks; its parts: {sorted(named)}")
    if parts:
        for name, param in model.named_parameters():
            param.requires_grad_(name.split(".")[0] in parts)
    return [p for p in model.parameters() if p.requires_grad]


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

    def __init__(self, config: LearnerConfig, progress: bool = True, world: World = SINGLE_PROCESS) -> None:
        cfg = config.train
        self.config, self.world, self.progress = config, world, progress and world.main
        self.device = resolve_device(cfg.device, world.local_rank, world.size)
        self.out = Path(config.out)
        self.view = StoreView(config.data.store, cache_dir=self.out / "hierarchies")
        stored = self.view.stored_split if config.data.split.source == "store" else None  # one read per subject
        tissue_of = self.view.tissue_of if config.data.split.by == "mesh+tissue" else None
        self.splits = split_subjects(self.view.subjects, self.view.mesh_of, config.data.split, stored, tissue_of)
        torch.manual_seed(cfg.seed)
        self.model: PNS = build_model(config.model, self.view.frames).to(self.device)
        self.objective: nn.Module = EpisodeObjective(
            self.model,
            cfg.lambda1,
            cfg.lambda2,
            cfg.posterior_targets or None,
            cfg.c_from,
            cfg.gate_loss,
            cfg.cc_loss,
            cfg.reconstruction,
            cfg.tissue_loss,
        )
        self.optimizer = torch.optim.Adam(trainable_parameters(self.model, cfg.trainable), lr=cfg.lr)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, cfg.lr_halve_every, gamma=0.5)
        self.scaler = torch.amp.GradScaler(self.device.type, enabled=cfg.precision == "fp16")
        self.epoch, self.history, self.best, self.steps_taken = 0, [], math.inf, 0
        self._datasets: dict[tuple[str, ...], EpisodeDataset] = {}
        self._loaders: dict[tuple, DataLoader] = {}
        self.warm_start = self._warm_start(Path(cfg.init)) if cfg.init else None

    # -- checkpoints -------------------------------------------------------
    def state(self) -> dict:
        """Everything needed to resume (tensors and plain containers only)."""
        return {
            "kind": "model",
            "config": self.config.to_dict(),
            "frames": self.view.frames,
            "times": self.view.times.tolist(),
            "splits": self.splits,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "scaler": self.scaler.state_dict(),
            "epoch": self.epoch,
            "history": self.history,
            "best_validation": self.best,
            # the template its episodes read maps through; without maps, computed from the store when asked for
            **({"ap_template": self.ap_template} if self.config.data.episodes.activation_maps else {}),
        }

    @cached_property
    def ap_template(self) -> dict:
        """The training subjects' action-potential template (:mod:`learner.activation_maps`), for activation maps."""
        return template_from_store(self.config.data.store, self.splits["train"]).to_dict()

    def _warm_start(self, path: Path) -> dict[str, list[str]]:
        """Copy the parameters of matching name and shape from a trained checkpoint (fine-tuning).

        The checkpoint (a file or a shipped model's name) must not have been
        trained on a subject this run holds out for validation or test. A
        maps encoder the checkpoint lacks starts as a copy of its context
        encoder (the same network, to be fine-tuned on maps). Returns the names
        copied and those left at their fresh initialisation.
        """
        ckpt = load_checkpoint(path, kind="model")
        held_out = set(ckpt["splits"].get("train", ())) & {*self.splits["validation"], *self.splits["test"]}
        if held_out:
            raise InputError(
                f"train.init {path} was trained on other subject splits: it saw {len(held_out)} subject(s) this "
                f"run holds out, e.g. {sorted(held_out)[0]!r} (data.split must match)"
            )
        own = self.model.state_dict()
        weights = dict(ckpt["model"])
        for name, value in ckpt["model"].items():
            if name.startswith("context_encoder."):
                weights.setdefault(name.replace("context_encoder.", "maps_encoder.", 1), value)
        taken = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape}
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
        if ckpt.get("scaler"):
            self.scaler.load_state_dict(ckpt["scaler"])
        self.epoch, self.history, self.best = ckpt["epoch"], list(ckpt["history"]), ckpt["best_validation"]

    def training_mean(self) -> float:
        """Mean potential of the first epoch's training episodes (context and targets, every node and frame)."""
        total, count = 0.0, 0
        for ep in self._episodes(self.splits["train"], 0):
            for u in (ep.context_u, ep.target_u):
                total, count = total + float(u.double().sum()), count + u.numel()
        return total / max(count, 1)

    # -- one epoch ---------------------------------------------------------
    def _dataset(self, subjects: list[str], epoch: int) -> EpisodeDataset:
        """The episodes of ``subjects`` (built and store-checked once per subject list) set to ``epoch``."""
        key = tuple(subjects)
        if key not in self._datasets:
            episodes = self.config.data.episodes
            template = ApTemplate.from_dict(self.ap_template) if episodes.activation_maps else None
            self._datasets[key] = EpisodeDataset(
                self.config.data.store, subjects, episodes, seed=self.config.train.seed, template=template
            )
        self._datasets[key].set_epoch(epoch)
        return self._datasets[key]

    def _episodes(self, subjects: list[str], epoch: int, world: World = SINGLE_PROCESS) -> DataLoader:
        """``world.rank``'s share of an epoch's episodes, read by ``data.workers`` loader processes.

        The loader and its worker processes last as long as the trainer (they
        take the dataset as sharded when they start, and the epoch from it at
        each pass): starting workers every epoch cost about 4 s, a tenth of an
        epoch of the default config on one process and a sixth on two.
        """
        ds = self._dataset(subjects, epoch)
        ds.shard(world.rank, world.size)
        key = (tuple(subjects), world.rank, world.size)
        if key not in self._loaders:
            workers = self.config.data.workers
            cuda = self.device.type == "cuda"
            self._loaders[key] = DataLoader(
                ds, batch_size=None, num_workers=workers, pin_memory=cuda, persistent_workers=workers > 0
            )
        return self._loaders[key]

    def _hierarchy(self, mesh_id: str) -> MeshHierarchy:
        model = self.config.model
        return on_device(self.view.hierarchy(mesh_id, model.levels, model.coarsest, model.working_nodes), self.device)

    def _last_good(self) -> str:
        """Where the last good checkpoint is, or that none was written yet."""
        last = self.out / "last.pt"
        return (
            f"the last good checkpoint is {last}" if last.is_file() else f"no checkpoint was written yet in {self.out}"
        )

    def _kl_weight(self) -> float:
        ramp = self.config.train.kl_anneal_epochs
        return 1.0 if ramp <= 0 else min(1.0, (self.epoch + 1) / ramp)

    def _frames(self, generator: torch.Generator) -> torch.Tensor | None:
        k = self.config.train.loss_frames
        if k <= 0 or k >= self.view.frames:
            return None
        return torch.randperm(self.view.frames, generator=generator)[:k].sort().values.to(self.device)

    def episode_generator(self, subject_id: str) -> torch.Generator:
        """The generator of a training episode's loss frames and posterior draws, from (seed, epoch, subject)."""
        key = [self.config.train.seed, self.epoch, self.splits["train"].index(subject_id)]
        return torch.Generator().manual_seed(int(np.random.SeedSequence(key).generate_state(1, np.uint64)[0]))

    def episode_terms(self, episode: Episode) -> LossTerms:
        """The loss of one training episode of the current epoch, on the trainer's device and in its precision."""
        generator = self.episode_generator(episode.subject_id)
        frames = self._frames(generator)
        ep = episode.to(self.device, non_blocking=True)
        with autocast(self.device, self.config.train.precision):
            return self.objective(ep, self._hierarchy(ep.mesh_id), self._kl_weight(), frames, generator)

    def train_epoch(self, on_step: StepHook | None = None) -> dict[str, float]:
        """One episode per training subject; returns the mean loss terms and the gradient norms' median and maximum.

        ``on_step(episode, terms, grad_norm)`` is called after each backward pass
        and clipping, before the optimiser step (diagnostics:
        ``bench/training_stability.py``); ``grad_norm`` is the norm before clipping
        (of the gradient averaged over the ranks). Loss means are over the whole
        epoch, every rank's episodes.
        """
        cfg, m, world = self.config.train, self.model, self.world
        m.train()
        episodes = len(self.splits["train"])
        keys = [f.name for f in fields(LossTerms)]
        sums, real = dict.fromkeys(keys, 0.0), 0
        norms: list[float] = []
        bar = tqdm(
            self._episodes(self.splits["train"], self.epoch, world),
            total=world.steps(episodes),
            disable=not (self.progress and sys.stderr.isatty()),  # in a log, the per-epoch lines show progress
            leave=False,
            desc=f"epoch {self.epoch + 1}/{cfg.epochs}",
        )
        for step, ep in enumerate(bar):
            weight = world.weight(step, episodes)  # 1.0 on one process
            terms = self.episode_terms(ep)
            self.optimizer.zero_grad(set_to_none=True)
            self.scaler.scale(terms.total * weight).backward()
            self.scaler.unscale_(self.optimizer)
            grad_norm = torch.nn.utils.clip_grad_norm_(m.parameters(), cfg.grad_clip)
            if not torch.isfinite(terms.total) or (not self.scaler.is_enabled() and not torch.isfinite(grad_norm)):
                raise TrainingDiverged(
                    f"non-finite loss or gradient at epoch {self.epoch + 1}, subject {ep.subject_id}; "
                    f"{self._last_good()} (lower train.lr or train.grad_clip)"
                )
            if on_step is not None:
                on_step(ep, terms, float(grad_norm))
            self.scaler.step(self.optimizer)
            self.scaler.update()
            self.steps_taken += 1
            kill_point(world, self.steps_taken)
            norms.append(float(grad_norm))
            if weight > 0:
                real += 1
                for k, v in terms.as_floats().items():
                    sums[k] += v
                bar.set_postfix(loss=f"{sums['total'] / real:.4g}", mse=f"{sums['target_mse'] / real:.3g}")
        *totals, real = world.all_sum([*sums.values(), real], self.device)
        means = {k: v / max(real, 1) for k, v in zip(keys, totals)}
        return {**means, "grad_norm_median": statistics.median(norms), "grad_norm_max": max(norms)}

    @torch.no_grad()
    def validate(self) -> float:
        """Mean target MSE on fixed validation episodes (c = mean of p(c | Y)), sharded over the ranks."""
        subjects = self.splits["validation"] or self.splits["train"]
        self.model.eval()
        total, n = 0.0, 0
        ds = self._dataset(subjects, VALIDATION_EPOCH)
        for i in ds.order()[self.world.rank :: self.world.size]:
            ep = ds.episode(i).to(self.device)
            hier = self._hierarchy(ep.mesh_id)
            with autocast(self.device, self.config.train.precision):
                c, evidence = None, SiteEvidence.of(ep)
                if ep.context_ecg is not None:
                    c, evidence = self.model.embed_ecg(ep.context_ecg, ep.lead_field, ep.context_sites, hier).mu, None
                elif self.model.conditioned:
                    c = self.model.embed(ep.context_obs, ep.observed, hier, ep.context_recorded).mu
                pred = self.model.generate(ep.target_sites, hier, c, evidence=evidence)
            total, n = total + float(((pred.float() - ep.target_u) ** 2).mean()), n + 1
        total, n = self.world.all_sum([total, n], self.device)
        return total / max(n, 1)

    # -- the loop ----------------------------------------------------------
    def fit(self, on_epoch: Callable[[dict], None] | None = None, on_step: StepHook | None = None) -> TrainResult:
        """Train until ``train.epochs`` (or ``train.max_minutes``), checkpointing every epoch."""
        cfg, main = self.config.train, self.world.main
        tune_allocator()
        set_threads(cfg.threads)
        if main:
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "config.json").write_text(json.dumps(self.config.to_dict(), indent=2))
        if self.epoch == 0 and not self.history and main:  # DDP gives the other ranks rank 0's parameters
            if self.warm_start is not None:
                record = {"init": self.config.train.init, **self.warm_start}
                (self.out / "warm_start.json").write_text(json.dumps(record))
            if self.warm_start is None or "decoder.out.bias" in self.warm_start["fresh"]:
                self.model.set_output_mean(self.training_mean())
        if self.world.size > 1 and not isinstance(self.objective, DistributedDataParallel):
            self.objective = DistributedDataParallel(self.objective)
        start, stopped, cost = time.perf_counter(), False, StepCost()
        while self.epoch < cfg.epochs:
            t0 = time.perf_counter()
            row = {"epoch": self.epoch + 1, "lr": self.optimizer.param_groups[0]["lr"], **self.train_epoch(on_step)}
            self.scheduler.step()
            self.epoch += 1
            row["seconds"] = time.perf_counter() - t0
            cost.epoch_s = max(cost.epoch_s, row["seconds"])
            due = self.epoch % cfg.validate_every == 0 or self.epoch == cfg.epochs
            over = self.epoch < cfg.epochs and cost.overruns(60 * cfg.max_minutes, time.perf_counter() - start, due)
            stopped = self.world.all_sum([float(over)], self.device)[0] > 0  # every rank stops together
            if due or stopped:
                t1 = time.perf_counter()
                row["val_target_mse"] = self.validate()
                cost.validation_s = max(cost.validation_s or 0.0, time.perf_counter() - t1)
                if row["val_target_mse"] < self.best:
                    self.best = row["val_target_mse"]
                    if main:
                        save_checkpoint(self.out / "best.pt", self.state())
            self.history.append(row)
            if main:
                save_checkpoint(self.out / "last.pt", self.state())
                self._log(row)
                if on_epoch is not None:
                    on_epoch(row)
            if stopped:
                break
        if main and not (self.out / "best.pt").exists():
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
            "gate_bce",
            "spatial_cc",
            "tissue_bce",
            "cv_log_error",
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
    """The configuration without what a resumed run may change (its length, time budget and device).

    Keys added to the configuration since the checkpoint was written take their defaults.
    """
    config = config_from_mapping(config).to_dict()
    train = {k: v for k, v in config["train"].items() if k not in ("epochs", "max_minutes", "device")}
    return {**config, "train": train}


def train(
    config: LearnerConfig, fresh: bool = False, progress: bool = True, on_epoch: Callable[[dict], None] | None = None
) -> TrainResult:
    """Train per ``config``; resumes from ``<out>/last.pt`` unless ``fresh``.

    Under ``torchrun`` (``WORLD_SIZE`` > 1) every rank calls this: each joins
    the process group, resumes from the same ``last.pt`` and trains its share.
    """
    with process_group(config.train.device) as world:
        trainer = Trainer(config, progress, world)
        last = Path(config.out) / "last.pt"
        if fresh:
            if world.main:
                for name in ("last.pt", "best.pt", "log.csv", "log.jsonl"):
                    (Path(config.out) / name).unlink(missing_ok=True)
        elif last.exists():
            trainer.resume(last)
        return trainer.fit(on_epoch)


def load_model(path: str | Path, device: torch.device | str = "cpu") -> tuple[PNS, LearnerConfig, dict]:
    """A trained model (eval mode, on ``device``), its config and the checkpoint dict."""
    ckpt = load_checkpoint(path, kind="model")
    config = config_from_mapping(ckpt["config"])
    model = build_model(config.model, ckpt["frames"])
    try:
        model.load_state_dict(ckpt["model"])
    except RuntimeError as exc:  # missing, unexpected or misshapen tensors
        first = next((line.strip() for line in str(exc).splitlines()[1:] if line.strip()), str(exc))
        raise InputError(f"{path}: its weights do not fit the model its config describes ({first[:200]})") from None
    return model.to(device).eval(), config, ckpt
