"""Training configuration: one TOML file, defaults in code, unknown keys refused.

Example (TOML)::

    out = "runs/default"  # run directory: checkpoints, logs, hierarchy cache

    [data]
    store = "default.zarr"  # relative paths are relative to this file
    [data.split]
    seed = 0
    test = 0.25  # source = "store": the store's canonical split instead
    [data.episodes]
    context = [1, 5]
    targets = 20
    observe = "surface"

    [model]
    kind = "metapns"  # or "pns" (same generator, no context embedding)

    [train]
    epochs = 100
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from learner.data.episodes import EpisodeSpec
from learner.data.split import SplitSpec
from learner.pretrained.shipped import resolve_reference
from learner.runtime import PRECISIONS, check_device
from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import ConfigError
from shared.location import resolve_location

__all__ = ["DataConfig", "ModelConfig", "TrainConfig", "LearnerConfig", "load_config", "config_from_mapping"]


@dataclass(frozen=True)
class DataConfig:
    """Where episodes come from and how they are drawn."""

    store: str = ""
    workers: int = 1  # DataLoader worker processes (0 = load in the training process)
    split: SplitSpec = field(default_factory=SplitSpec)
    episodes: EpisodeSpec = field(default_factory=EpisodeSpec)


@dataclass(frozen=True)
class ModelConfig:
    """Network sizes (defaults near the reference: channels 1-8-16-32-64-128, latent 64)."""

    kind: Literal["metapns", "pns"] = "metapns"
    channels: tuple[int, ...] = (8, 16, 32, 64)  # per encoder block, fine to coarse
    hidden: int = 128  # the 1x1 layers between the graph blocks and the latent space
    latent: int = 64  # channels of z_t and of c, per coarse node
    levels: int = 5  # graphs in the mesh hierarchy (len(channels) + 1)
    coarsest: int = 40  # nodes of the coarsest graph (approximately)
    coarse_blocks: int = 3  # graph blocks at the coarsest level before z_0 (a mesh-wide receptive field)
    decoder_skips: bool = False  # decoder blocks also see the stimulus encoder's features of their level
    stimulus_distance: bool = True  # the site's geodesic distance map joins its one-hot map as an input
    context_stride: int = 1  # the context encoder sees every k-th frame (1 = all, as in the paper)
    latent_norm: bool = True  # layer-normalise the latent state after each transition step (False: the reference)
    context_stimulus: bool = False  # metaPNS: c joins the stimulus features before the coarse blocks
    capture_gate: bool = False  # metaPNS: c at the site decides whether a wave starts (PNS.generate)
    capture_evidence: bool = False  # the gate also reads the context's peak at the site (SiteEvidence)
    working_nodes: int | None = None  # a finer mesh is seen as this many clusters (learner.graph.working); None: as is
    ecg_encoder: bool = False  # metaPNS: a second context encoder that reads 12-lead ECGs (learner.models.ecg_encoder)
    maps_encoder: bool = False  # metaPNS: a context encoder for activation-time maps, read up to each upstroke
    tissue_head: bool = False  # metaPNS: c also gives abnormal tissue per node and the CV (learner.models.tissue_head)

    def __post_init__(self) -> None:
        if self.levels != len(self.channels) + 1:
            raise ConfigError(
                f"model.levels ({self.levels}) must be len(model.channels) + 1 ({len(self.channels) + 1})"
            )
        if min(self.channels + (self.hidden, self.latent)) < 1:
            raise ConfigError("model channel counts must be positive")
        if self.context_stride < 1:
            raise ConfigError(f"model.context_stride must be >= 1, got {self.context_stride}")
        if self.coarsest < 4:
            raise ConfigError(f"model.coarsest must be >= 4, got {self.coarsest}")
        if self.working_nodes is not None and self.working_nodes < 2 * self.coarsest:
            raise ConfigError(
                f"model.working_nodes must be at least twice model.coarsest ({2 * self.coarsest}), "
                f"got {self.working_nodes}"
            )
        for name in ("ecg_encoder", "maps_encoder", "tissue_head"):
            if getattr(self, name) and self.kind != "metapns":
                raise ConfigError(f"model.{name} reads the context's c: set model.kind = 'metapns'")
        if self.capture_evidence and not self.capture_gate:
            raise ConfigError("model.capture_evidence is an input of the capture gate: set model.capture_gate too")


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation (the reference paper: Adam 1e-3 halved every 50 epochs, lambda1 1e-4, lambda2 0.1)."""

    epochs: int = 100
    lr: float = 1e-3
    lr_halve_every: int = 50
    grad_clip: float = 10.0
    lambda1: float = 1e-4
    lambda2: float = 0.1
    kl_anneal_epochs: int = 0  # KL weights ramp linearly from 0 over this many epochs (0 = off)
    loss_frames: int = 0  # decode only this many random frames per episode for the loss (0 = all)
    posterior_targets: int = 0  # targets that join the context in q(c | Y u X) (0 = all)
    c_from: Literal["posterior", "context"] = "posterior"  # training draws c from q(c | Y u X) or p(c | Y)
    gate_loss: float = 0.0  # weight of the capture gate's cross-entropy against "the stimulus starts a wave" (0 = off)
    cc_loss: float = (
        0.0  # weight of 1 - spatial correlation of each decoded frame, as learner.metrics.spatial_cc (0 = off)
    )
    tissue_loss: float = 0.0  # weight of the tissue head's abnormal-tissue BCE plus squared log-CV error (0 = off)
    seed: int = 0
    threads: int = 0  # torch intra-op threads (0 = torch's default)
    max_minutes: float = 0.0  # wall-time budget: no epoch starts that would end past it (0 = no limit)
    validate_every: int = 5  # epochs between validation passes (best checkpoint kept)
    init: str = ""  # warm start: a checkpoint or a shipped model's name; its matching parameters start this run
    reconstruction: bool = True  # False: fit the KL terms alone, without running the generator (an encoder's stage)
    trainable: tuple[str, ...] = ()  # the model's parts (top-level modules) trained; the rest frozen (empty: all)
    device: str = "auto"  # auto (CUDA where available), cpu, cuda or cuda:N
    precision: str = "fp32"  # fp32, or autocast to bf16 / fp16 (docs/training.md measures bf16)

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.lr <= 0 or self.lr_halve_every < 1:
            raise ConfigError("train.epochs, train.lr and train.lr_halve_every must be positive")
        if self.lambda1 < 0 or self.lambda2 < 0 or self.grad_clip <= 0:
            raise ConfigError("train.lambda1/lambda2 must be >= 0 and train.grad_clip > 0")
        if self.gate_loss < 0:
            raise ConfigError(f"train.gate_loss must be >= 0, got {self.gate_loss}")
        if self.cc_loss < 0:
            raise ConfigError(f"train.cc_loss must be >= 0, got {self.cc_loss}")
        if self.tissue_loss < 0:
            raise ConfigError(f"train.tissue_loss must be >= 0, got {self.tissue_loss}")
        if self.trainable and not self.init:
            raise ConfigError("train.trainable freezes the rest of the model: give the trained model as train.init")
        if not self.reconstruction and (self.gate_loss or self.cc_loss):
            raise ConfigError("train.gate_loss and train.cc_loss need the generator's output: set train.reconstruction")
        check_device(self.device, "train.device")
        if self.precision not in PRECISIONS:
            raise ConfigError(f"train.precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")


@dataclass(frozen=True)
class LearnerConfig:
    """A whole training run."""

    out: str = "runs/default"
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        if self.data.episodes.targets < 1:
            raise ConfigError(
                "data.episodes.targets must be >= 1: training fits the model to each episode's targets, got 0"
            )
        if self.data.episodes.ecg > 0 and not self.model.ecg_encoder:
            raise ConfigError("data.episodes.ecg records context sets as ECGs: set model.ecg_encoder = true")
        if self.train.tissue_loss > 0 and not self.model.tissue_head:
            raise ConfigError("train.tissue_loss fits the tissue head: set model.tissue_head = true")
        if self.train.gate_loss > 0 and not (self.model.kind == "metapns" and self.model.capture_gate):
            raise ConfigError(
                "train.gate_loss fits the capture gate: set model.kind = 'metapns' and model.capture_gate"
            )

    def to_dict(self) -> dict:
        """Plain-dict form (stored in checkpoints, reloaded with :func:`config_from_mapping`)."""
        return to_mapping(self)


def config_from_mapping(data: dict, base: Path | None = None) -> LearnerConfig:
    """Validate a mapping; relative ``out``, ``data.store`` and ``train.init`` are resolved against ``base``."""
    cfg = from_mapping(LearnerConfig, data)
    if not cfg.data.store:
        raise ConfigError("data.store is required: the dataset store built by `simgen build`")
    if base is not None:
        store = resolve_location(cfg.data.store, base)
        init = resolve_reference(cfg.train.init, base)
        cfg = replace(
            cfg,
            out=str((base / cfg.out).resolve()),
            data=replace(cfg.data, store=store),
            train=replace(cfg.train, init=init),
        )
    return cfg


def load_config(path: str | Path) -> LearnerConfig:
    """Read and validate a TOML config file."""
    path = Path(path)
    return config_from_mapping(load_toml(path), base=path.parent)
