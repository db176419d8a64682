"""Training across processes with torch.distributed: ranks and the process group.

``torchrun --nproc-per-node N -m learner train CFG`` (or ``learner train CFG
--nproc N``, which starts the same through torch's elastic launcher on
127.0.0.1) runs one training process per rank (:mod:`learner.train.launcher` starts them); each wraps the model in
``DistributedDataParallel`` (gloo on the CPU, NCCL on GPUs). An epoch's
subject order is cut into global steps of ``W`` episodes: rank ``r`` trains
position ``i W + r`` at step ``i``, and DDP averages the gradients. A last
step with fewer than ``W`` episodes is padded: the ranks past the end train
a repeated episode with loss weight 0 and the others weight ``W / n``, so
the step's gradient is the mean over its ``n`` real episodes
(:meth:`World.weight`).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.distributed as dist

from learner.runtime import resolve_device

__all__ = ["KILL_AT_ENV", "World", "SINGLE_PROCESS", "world_from_env", "process_group", "kill_point"]

#: Test hook: ``"RANK:STEP"`` makes that rank SIGKILL itself at its STEP-th optimiser step (1-based).
KILL_AT_ENV = "LEARNER_TEST_KILL_AT"


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
