"""Meta-training: the training loop, its loss, checkpoints, and training across processes.

:func:`train` runs a config (resuming from ``<out>/last.pt``), :func:`load_model` reads a trained
model back; :func:`launch` starts ``--nproc`` processes (:mod:`learner.train.distributed`).
"""

from __future__ import annotations

from learner.checkpoint import CHECKPOINT_FORMAT, load_checkpoint, save_checkpoint
from learner.train.distributed import World
from learner.train.launcher import RankFailed, launch
from learner.train.loss import EpisodeObjective, LossTerms, episode_loss
from learner.train.trainer import Trainer, TrainingDiverged, TrainResult, load_model, train

__all__ = [
    "train",
    "Trainer",
    "TrainResult",
    "TrainingDiverged",
    "load_model",
    "launch",
    "RankFailed",
    "World",
    "EpisodeObjective",
    "LossTerms",
    "episode_loss",
    "CHECKPOINT_FORMAT",
    "save_checkpoint",
    "load_checkpoint",
]
