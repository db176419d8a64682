"""Benchmark: what the readers' verification costs (shared.integrity) - single reads, episodes/s, a training epoch.

Every read of ``u`` or ``activation`` through :mod:`shared.reader`, the
learner's episodes, ``SimulationDataset`` and ``export-vtk`` checks each chunk
it touches once per reader (done flag, shard indices, content fingerprint from
the inner chunks' CRC32C) and the rows it decodes (finite ``u``). This bench
builds the store of :mod:`bench.store_read` (one ~2000-node LV x 4 tissue
settings x 200 sites, 64 sites per build task, sharded) and measures each
read path with the check and with it switched off (``SubjectReader.check_chunk``
replaced by a no-op, in this process only):

- **one simulation** (``rows("u", [site])`` of a random subject and site,
  ``--reads`` of them, median, store in the page cache), the chunk checked
  again on every read (the worst case: a fresh reader per read);
- **episodes/s** of :class:`learner.data.episodes.EpisodeDataset` (1-5
  context + 10 target sites on the surface, as :mod:`bench.store_read`);
- **a training epoch** (``learner.train.trainer.train``, a small model
  (channels 4-8, latent 8: reading is a larger share of its epoch than of the
  default model's), 1-5 context + 8 targets, loss on 20 frames, one episode
  per subject and epoch; median of ``--epochs`` epochs, in which the readers
  check their chunks anew).

Run: ``.venv/bin/python -m bench.read_verification [--out DIR]`` (DIR gets read_verification.md and .json).
``--publish`` writes the table into the block ``read_verification`` of docs/results.md with the command and
the machine.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from bench.common import add_out_argument, add_publish_argument, check_publish, machine_line, publish_out, write_out
from bench.store_read import bench_spec, warm
from learner.config import config_from_mapping
from learner.data.episodes import EpisodeDataset, EpisodeSpec
from learner.train.trainer import train
from shared.integrity import SubjectReader
from shared.reader import subject_ids
from simgen.store.runner import build


@contextmanager
def checks(on: bool):
    """Chunk checks as shipped (``on``) or skipped, in this process."""
    original = SubjectReader.check_chunk
    if not on:
        SubjectReader.check_chunk = lambda self, chunk, name="u", site=None: True
    try:
        yield
    finally:
        SubjectReader.check_chunk = original


def single_reads(store: Path, reads: int, seed: int = 0) -> float:
    """Median seconds of one verified row of ``u``, its chunk checked again each time."""
    rng = np.random.default_rng(seed)
    readers = {s: SubjectReader(store, s) for s in subject_ids(store)}
    ids = sorted(readers)
    times = []
    for _ in range(reads):
        reader = readers[ids[rng.integers(len(ids))]]
        site = int(rng.integers(reader.n_sites))
        reader._checked.clear()  # the worst case: every read checks its chunk
        start = time.perf_counter()
        reader.rows("u", [site])
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def episodes_per_second(store: Path, episodes: int) -> float:
    spec = EpisodeSpec(context=(1, 5), targets=10, observe="surface")
    ids = subject_ids(store)
    dataset = EpisodeDataset(store, ids, spec, seed=0, episodes_per_subject=-(-episodes // len(ids)))
    start = time.perf_counter()
    n = sum(1 for _ in dataset)
    return n / (time.perf_counter() - start)


def epoch_seconds(store: Path, out: Path, epochs: int) -> float:
    """Median wall time of a training epoch (one episode per subject) over ``epochs`` epochs."""
    config = config_from_mapping(
        {
            "out": str(out),
            "data": {
                "store": str(store),
                "workers": 0,
                "split": {"seed": 0, "validation": 0.0, "test": 0.0},
                "episodes": {"context": [1, 5], "targets": 8, "observe": "surface"},
            },
            # a small model: the store's share of an epoch is larger than with the default one
            "model": {"channels": [4, 8], "hidden": 16, "latent": 8, "levels": 3, "coarsest": 10, "coarse_blocks": 1},
            "train": {"epochs": epochs, "loss_frames": 20, "validate_every": epochs},
        }
    )
    seconds = []
    train(config, fresh=True, progress=False, on_epoch=lambda row: seconds.append(row["seconds"]))
    return statistics.median(seconds)


def run(args) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="read-verification-", dir=args.tmp))
    store = tmp / "store.zarr"
    build(bench_spec(args.nodes, 4, args.sites, args.chunk), store, workers=args.workers)
    warm(store)
    results = {}
    for label, on in (("unchecked", False), ("verified", True), ("unchecked again", False), ("verified again", True)):
        with checks(on):
            row = {
                "read_ms": 1e3 * single_reads(store, args.reads),
                "episodes_per_s": episodes_per_second(store, args.episodes),
                "epoch_s": epoch_seconds(store, tmp / f"run-{label.replace(' ', '-')}", args.epochs),
            }
        key = label.split()[0]
        best = results.setdefault(key, row)
        results[key] = {
            "read_ms": min(best["read_ms"], row["read_ms"]),
            "episodes_per_s": max(best["episodes_per_s"], row["episodes_per_s"]),
            "epoch_s": min(best["epoch_s"], row["epoch_s"]),
        }
    return results


def markdown(results: dict, args, seconds: float, header: bool = True) -> str:
    """The table; ``header``: with the machine and command lines first (``--publish`` writes its own)."""
    off, on = results["unchecked"], results["verified"]
    store = f"1 LV of ~{args.nodes} nodes x 4 settings x {args.sites} sites, {args.chunk} sites per shard"
    if header:
        lines = [
            f"Machine: {machine_line()}; store: {store}.",
            f"Command: `.venv/bin/python -m bench.read_verification` ({seconds:.0f} s); best of two passes each.",
        ]
    else:
        lines = [f"Store: {store}; {seconds:.0f} s in all; best of two passes each."]
    lines += [
        "",
        "| reads | one simulation (ms) | episodes/s | training epoch (s) |",
        "|---|---:|---:|---:|",
        f"| unchecked | {off['read_ms']:.2f} | {off['episodes_per_s']:.1f} | {off['epoch_s']:.2f} |",
        f"| verified | {on['read_ms']:.2f} | {on['episodes_per_s']:.1f} | {on['epoch_s']:.2f} |",
        f"| cost | {100 * (on['read_ms'] / off['read_ms'] - 1):+.1f}% | "
        f"{100 * (off['episodes_per_s'] / on['episodes_per_s'] - 1):+.1f}% | "
        f"{100 * (on['epoch_s'] / off['epoch_s'] - 1):+.1f}% |",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, default=2000)
    p.add_argument("--sites", type=int, default=200)
    p.add_argument("--chunk", type=int, default=64)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--reads", type=int, default=200, help="single-simulation reads per pass")
    p.add_argument("--episodes", type=int, default=200, help="episodes per episodes/s pass")
    p.add_argument("--epochs", type=int, default=5, help="training epochs per pass (median kept)")
    p.add_argument("--tmp", type=Path, default=None, help="folder for the store (default: the system's temp)")
    add_out_argument(p, "read_verification")
    add_publish_argument(p, "read_verification")
    args = p.parse_args(argv)
    check_publish(args.publish)
    start = time.perf_counter()
    results = run(args)
    seconds = time.perf_counter() - start
    text = markdown(results, args, seconds)
    print(text)
    publish_out(args.publish, "read_verification", markdown(results, args, seconds, header=False))
    payload = {"args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}, **results}
    write_out(args.out, "read_verification", text, payload, indent=None)


if __name__ == "__main__":
    main()
