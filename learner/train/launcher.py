"""The ``--nproc`` launcher: ``learner train CFG --nproc N`` starts N training processes (torch elastic launch).

It does on 127.0.0.1 what ``torchrun --nproc-per-node N -m learner train CFG``
does; each process then joins the process group of :mod:`learner.train.distributed`.
"""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Callable
from pathlib import Path

import torch.distributed as dist

from learner.config import LearnerConfig
from learner.runtime import resolve_device
from learner.train.distributed import world_from_env
from learner.train.trainer import TrainingDiverged, TrainResult, train

__all__ = ["RankFailed", "launch"]


class RankFailed(RuntimeError):
    """A training process of a multi-process run failed; the message names it and the checkpoint to resume."""


def _run_rank(config: LearnerConfig, fresh: bool, on_epoch: Callable[[dict], None] | None) -> TrainResult:
    """One process of a ``--nproc`` run: train, and report an expected failure on one line without a traceback."""
    try:
        return train(config, fresh=fresh, progress=world_from_env().main, on_epoch=on_epoch)
    except (ValueError, OSError, TrainingDiverged, dist.DistError) as exc:
        print(f"rank {world_from_env().rank}: {exc}", flush=True)
        raise SystemExit(1) from None


def _quiet_launcher_logs() -> None:
    """Keep the elastic agent's per-failure log lines and tracebacks off the terminal (:func:`launch` reports)."""
    for name in ("torch.distributed.elastic", "torch.distributed.launcher", "torch.multiprocessing"):
        logger = logging.getLogger(name)
        logger.addHandler(logging.NullHandler())
        logger.propagate = False


def _failure_message(exc: Exception, nproc: int, out: Path) -> str:
    """One line: which rank failed how, and where the run resumes."""
    from torch.distributed.elastic.multiprocessing.errors import ChildFailedError

    parts = []
    if isinstance(exc, ChildFailedError):
        first, _ = exc.get_first_failure()
        for rank, failure in sorted(exc.failures.items(), key=lambda item: item[0] != first):
            how = (
                f"was killed by {failure.signal_name()}"
                if failure.exitcode < 0
                else f"exited with code {failure.exitcode}"
            )
            parts.append(f"rank {rank} {how}")
    else:
        parts.append(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    last = out / "last.pt"
    resume = f"{last} resumes it (rerun the same command)" if last.exists() else "no checkpoint was written yet"
    return f"training on {nproc} processes failed: {', '.join(parts)}; {resume}"


def launch(
    config: LearnerConfig, nproc: int, fresh: bool = False, on_epoch: Callable[[dict], None] | None = None
) -> TrainResult:
    """Train on ``nproc`` local processes, as ``torchrun --nproc-per-node nproc`` would; returns rank 0's result.

    Raises :class:`RankFailed` (one line, no traceback) when any rank fails;
    ``<out>/last.pt`` then holds the last completed epoch.
    """
    from torch.distributed.launcher.api import LaunchConfig, elastic_launch

    resolve_device(config.train.device, 0, nproc)  # a bad device fails here, once, not in every rank
    if nproc > 1:  # as torchrun does: one process per core share instead of every process on every core
        os.environ.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // nproc)))
    _quiet_launcher_logs()
    launch_config = LaunchConfig(
        min_nodes=1,
        max_nodes=1,
        nproc_per_node=nproc,
        run_id=uuid.uuid4().hex,
        rdzv_backend="c10d",
        rdzv_endpoint="127.0.0.1:0",
        max_restarts=0,
        local_addr="127.0.0.1",
    )
    try:
        return elastic_launch(launch_config, _run_rank)(config, fresh, on_epoch)[0]
    except Exception as exc:  # ChildFailedError, or a rendezvous error before any rank started
        raise RankFailed(_failure_message(exc, nproc, Path(config.out))) from None
