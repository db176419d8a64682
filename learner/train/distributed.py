"""Training across processes with torch.distributed: ranks, the process group and the ``--nproc`` launcher.

``torchrun --nproc-per-node N -m learner train CFG`` (or ``learner train CFG
--nproc N``, which starts the same through torch's elastic launcher on
127.0.0.1) runs one training process per rank; each wraps the model in
``DistributedDataParallel`` (gloo on the CPU, NCCL on GPUs). An epoch's
subject order is cut into global steps of ``W`` episodes: rank ``r`` trains
position ``i W + r`` at step ``i``, and DDP averages the gradients. A last
step with fewer than ``W`` episodes is padded: the ranks past the end train
a repeated episode with loss weight 0 and the others weight ``W / n``, so
the step's gradient is the mean over its ``n`` real episodes
(:meth:`World.weight`).
"""

from __future__ import annotations

import logging
import os
import signal
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch
import torch.distributed as dist

from learner.runtime import resolve_device

if TYPE_CHECKING:
    from learner.config import LearnerConfig
    from learner.train.trainer import TrainResult

__all__ = [
    "KILL_AT_ENV",
    "World",
    "SINGLE_PROCESS",
    "RankFailed",
    "world_from_env",
    "process_group",
    "kill_point",
    "launch",
]

#: Test hook: ``"RANK:STEP"`` makes that rank SIGKILL itself at its STEP-th optimiser step (1-based).
KILL_AT_ENV = "LEARNER_TEST_KILL_AT"


class RankFailed(RuntimeError):
    """A training process of a multi-process run failed; the message names it and the checkpoint to resume."""


@dataclass(frozen=True)
class World:
    """This process's place among the training processes (``size`` 1: a plain single-process run)."""

    rank: int = 0
    size: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Rank 0: the process that writes checkpoints and logs."""
        return self.rank == 0

    def steps(self, episodes: int) -> int:
        """Global steps of an epoch of ``episodes`` episodes (the last one may be short)."""
        return -(-episodes // self.size)

    def weight(self, step: int, episodes: int) -> float:
        """Loss weight of this rank's episode at ``step``: ``W / n`` in a step of ``n`` real episodes, 0 for padding."""
        first = step * self.size
        if first + self.rank >= episodes:
            return 0.0
        return self.size / min(self.size, episodes - first)

    def all_sum(self, values: Sequence[float], device: torch.device) -> list[float]:
        """Element-wise sum of ``values`` over every rank (float64)."""
        if self.size == 1:
            return [float(v) for v in values]
        total = torch.tensor(values, dtype=torch.float64, device=device)
        dist.all_reduce(total)
        return total.tolist()


#: The world of a plain single-process run.
SINGLE_PROCESS = World()


def world_from_env() -> World:
    """The world that ``torchrun`` (or the elastic launcher) describes in ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``."""
    env = os.environ
    return World(int(env.get("RANK", 0)), int(env.get("WORLD_SIZE", 1)), int(env.get("LOCAL_RANK", 0)))


@contextmanager
def process_group(device: str) -> Iterator[World]:
    """Join the process group for the duration of a run (nothing to join when the world size is 1)."""
    world = world_from_env()
    if world.size == 1:
        yield world
        return
    placed = resolve_device(device, world.local_rank, world.size)
    if placed.type == "cuda":
        torch.cuda.set_device(placed)
    dist.init_process_group("nccl" if placed.type == "cuda" else "gloo", rank=world.rank, world_size=world.size)
    try:
        yield world
    finally:
        dist.destroy_process_group()


def kill_point(world: World, step: int) -> None:
    """SIGKILL this process at optimiser step ``step`` when :data:`KILL_AT_ENV` names its rank and that step."""
    target = os.environ.get(KILL_AT_ENV, "")
    if target and target == f"{world.rank}:{step}":
        os.kill(os.getpid(), signal.SIGKILL)


def _run_rank(config: LearnerConfig, fresh: bool, on_epoch: Callable[[dict], None] | None) -> TrainResult:
    """One process of a ``--nproc`` run: train, and report an expected failure on one line without a traceback."""
    from learner.train.trainer import TrainingDiverged, train

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
