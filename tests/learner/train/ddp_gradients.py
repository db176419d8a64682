"""Run by ``test_distributed.py`` under torchrun: one epoch on every rank, saving each step's gradients.

Usage: ``torchrun --nproc-per-node 2 ddp_gradients.py CONFIG.toml OUT_DIR`` writes
``OUT_DIR/grads-<rank>.pt``: per optimiser step, the gradients after DDP's averaging.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from learner.config import load_config
from learner.train.distributed import process_group
from learner.train.trainer import Trainer


def main(config: Path, out: Path) -> None:
    with process_group("cpu") as world:
        trainer = Trainer(load_config(config), progress=False, world=world)
        steps: list[list[torch.Tensor]] = []
        trainer.fit(on_step=lambda *_: steps.append([p.grad.clone() for p in trainer.model.parameters()]))
        torch.save(steps, out / f"grads-{world.rank}.pt")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
