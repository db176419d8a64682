"""Benchmark: training episodes per second on 1 process x 1 thread, 1 process x 2 threads and 2 processes x 1 thread.

Each set-up trains the same run side by side in one invocation: ``--config`` (default
``specs/train-default.toml``) on ``--store`` (default ``data/default.zarr``) for ``--epochs`` epochs, on
the CPU, from scratch, in a fresh child process (so no cache or allocator state carries over).
Two processes is ``learner train --nproc 2``: DistributedDataParallel over gloo, each rank one
thread and one loader worker. The rate of an epoch is its training episodes over its training
time (``seconds`` in ``log.jsonl``, rank 0; validation excluded); the first epoch also pays for
loader start-up and the geodesic distance rows of new sites, so later epochs are reported apart.
The ratio it exists to show: 2 processes over 1 process x 1 thread (goal >= 1.7x on 2 cores).

Run: ``.venv/bin/python -m bench.training_parallel [--epochs 2] [--store PATH] [--config TOML] [--out DIR]``.
``--publish`` writes the table into the block ``training_parallel`` of docs/results.md with the command and
the machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.common import add_out_argument, add_publish_argument, check_publish, machine_line, publish_out, write_out

ROOT = Path(__file__).resolve().parent.parent
#: (name, processes, threads per process)
SETUPS = (("1 process x 1 thread", 1, 1), ("1 process x 2 threads", 1, 2), ("2 processes x 1 thread", 2, 1))
GOAL = 1.7


def run_setup(store: str, config: Path, out: Path, epochs: int, nproc: int, threads: int) -> None:
    """One set-up, in this (child) process: train from scratch and leave ``out/log.jsonl``."""
    from learner.config import load_config
    from learner.train.launcher import launch
    from learner.train.trainer import train

    cfg = load_config(config)
    cfg = dataclasses.replace(
        cfg,
        out=str(out),
        data=dataclasses.replace(cfg.data, store=store),
        train=dataclasses.replace(cfg.train, epochs=epochs, threads=threads, device="cpu"),
    )
    if nproc > 1:
        launch(cfg, nproc, fresh=True)
    else:
        train(cfg, fresh=True, progress=False)


def rates(out: Path, episodes: int) -> tuple[float, float | None]:
    """Episodes per second of the first epoch and the mean of the later ones (None with one epoch)."""
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    per_epoch = [episodes / row["seconds"] for row in rows]
    return per_epoch[0], statistics.mean(per_epoch[1:]) if len(per_epoch) > 1 else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", default=str(ROOT / "data" / "default.zarr"))
    parser.add_argument("--config", type=Path, default=ROOT / "specs" / "train-default.toml")
    parser.add_argument("--epochs", type=int, default=2)
    add_out_argument(parser, "training_parallel")
    parser.add_argument("--setup", type=int, nargs=3, help=argparse.SUPPRESS)  # a child's run: nproc threads index
    parser.add_argument("--run-dir", type=Path, help=argparse.SUPPRESS)
    add_publish_argument(parser, "training_parallel")
    args = parser.parse_args()
    if args.setup:
        nproc, threads, _ = args.setup
        run_setup(args.store, args.config, args.run_dir, args.epochs, nproc, threads)
        return
    check_publish(args.publish)

    from learner.config import load_config
    from learner.data.split import split_subjects
    from learner.store_view import StoreView

    cfg = load_config(args.config)
    view = StoreView(args.store)
    stored = view.stored_split if cfg.data.split.source == "store" else None
    episodes = len(split_subjects(view.subjects, view.mesh_of, cfg.data.split, stored)["train"])
    results, load = [], os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        for index, (name, nproc, threads) in enumerate(SETUPS):
            run_dir = Path(tmp) / f"setup{index}"
            command = [
                sys.executable,
                "-m",
                "bench.training_parallel",
                "--store",
                args.store,
                "--config",
                str(args.config),
            ]
            command += ["--epochs", str(args.epochs), "--setup", str(nproc), str(threads), str(index)]
            subprocess.run(
                [*command, "--run-dir", str(run_dir)], check=True, env={**os.environ, "OMP_NUM_THREADS": "1"}
            )
            first, later = rates(run_dir, episodes)
            results.append({"setup": name, "processes": nproc, "threads": threads, "first": first, "later": later})
    base = results[0]["later"] or results[0]["first"]
    lines = [
        f"Training episodes per second, {episodes} episodes per epoch, {args.epochs} epoch(s) per set-up; "
        f"{machine_line()}, "
        f"load average {load:.1f} at the start.\n",
        "| set-up | episodes/s, epoch 1 | episodes/s, epochs 2+ | over 1 process x 1 thread |",
        "|---|---:|---:|---:|",
    ]
    for r in results:
        rate = r["later"] or r["first"]
        later = f"{r['later']:.3f}" if r["later"] is not None else "-"
        lines.append(f"| {r['setup']} | {r['first']:.3f} | {later} | {rate / base:.2f}x |")
    ratio = (results[2]["later"] or results[2]["first"]) / base
    lines.append(f"\n2 processes over 1 process x 1 thread: {ratio:.2f}x")
    table = "\n".join(lines)
    print(f"{table} (goal >= {GOAL}x)")
    publish_out(args.publish, "training_parallel", table)
    write_out(args.out, "training_parallel", table + "\n", {"episodes": episodes, "results": results}, indent=None)


if __name__ == "__main__":
    main()
