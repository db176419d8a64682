"""Benchmark: what bf16 / fp16 autocast (``train.precision``) does to the training loss, against fp32.

A model of ``--config`` (default ``specs/train-default.toml``) is trained in fp32 for ``--epochs`` epochs
on ``--store`` (default ``data/default.zarr``), so that it predicts more than the mean; then the
loss of the same ``--episodes`` training episodes (same frames, same posterior draws) is computed
with the same weights in fp32 and under each autocast precision, forward and backward. Reported per
precision: the relative difference of the total loss, of the target MSE and of the gradient norm
against fp32 (mean and largest over the episodes), and the time per episode. fp16 scales the loss
as training does (``torch.amp.GradScaler``). The block-sparse graph convolutions stay in float32
under autocast (their CPU kernels have no half-precision version).

Run: ``.venv/bin/python -m bench.precision [--epochs 1] [--episodes 8] [--device cpu] [--out DIR]``.
The table is published in docs/training.md ("Mixed precision") with its machine and command.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bench.common import add_out_argument, machine_line, write_out
from learner.config import LearnerConfig, load_config
from learner.data.episodes import EpisodeDataset
from learner.train.trainer import Trainer

ROOT = Path(__file__).resolve().parent.parent
PRECISIONS = ("fp32", "bf16", "fp16")


def measure(config: LearnerConfig, state: dict, epoch: int, episodes: int) -> list[dict[str, float]]:
    """Loss terms, gradient norm and seconds of the first ``episodes`` training episodes of ``epoch``."""
    trainer = Trainer(config, progress=False)
    trainer.model.load_state_dict(state)
    trainer.epoch = epoch
    rows = []
    train = trainer.splits["train"]
    data = EpisodeDataset(config.data.store, train, config.data.episodes, seed=config.train.seed, epoch=epoch)
    for i in data.order()[:episodes]:
        ep = data.episode(i)
        trainer.optimizer.zero_grad(set_to_none=True)
        t0 = time.perf_counter()
        terms = trainer.episode_terms(ep)
        scaler = trainer.scaler  # fp16: the loss scaled as in training, so that no gradient underflows
        scaler.scale(terms.total).backward()
        norm = float(torch.nn.utils.clip_grad_norm_(trainer.model.parameters(), float("inf")))
        norm /= scaler.get_scale() if scaler.is_enabled() else 1.0
        loss = terms.as_floats()
        rows.append({"total": loss["total"], "target_mse": loss["target_mse"], "grad_norm": norm})
        rows[-1]["seconds"] = time.perf_counter() - t0
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", default=str(ROOT / "data" / "default.zarr"))
    parser.add_argument("--config", type=Path, default=ROOT / "specs" / "train-default.toml")
    parser.add_argument("--epochs", type=int, default=1)
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--device", default="cpu")
    add_out_argument(parser, "precision")
    args = parser.parse_args()

    base = load_config(args.config)
    with tempfile.TemporaryDirectory() as tmp:
        train = dataclasses.replace(base.train, epochs=args.epochs, device=args.device, validate_every=args.epochs)
        config = dataclasses.replace(base, out=tmp, data=dataclasses.replace(base.data, store=args.store), train=train)
        trained = Trainer(config, progress=False)
        trained.fit()
        state = {k: v.detach().clone() for k, v in trained.model.state_dict().items()}
        results = {
            p: measure(
                dataclasses.replace(config, train=dataclasses.replace(train, precision=p)),
                state,
                args.epochs,
                args.episodes,
            )
            for p in PRECISIONS
        }
    reference = results["fp32"]
    lines = [
        f"{args.episodes} training episodes of epoch {args.epochs + 1} after {args.epochs} fp32 epoch(s), "
        f"device {args.device}, {machine_line()}.\n",
        "| precision | total loss, relative difference: mean / max | target MSE | gradient norm | s per episode |",
        "|---|---:|---:|---:|---:|",
    ]
    for p, rows in results.items():
        cells = []
        for key in ("total", "target_mse", "grad_norm"):
            rel = np.array([abs(r[key] - f[key]) / abs(f[key]) for r, f in zip(rows, reference)])
            cells.append(f"{rel.mean():.1e} / {rel.max():.1e}")
        seconds = float(np.median([r["seconds"] for r in rows]))
        lines.append(f"| {p} | {' | '.join(cells)} | {seconds:.2f} |")
    table = "\n".join(lines)
    print(table)
    write_out(args.out, "precision", table + "\n", results, indent=None)


if __name__ == "__main__":
    main()
