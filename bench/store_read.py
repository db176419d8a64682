"""Benchmark: sharded vs unsharded result arrays - build time, store size, single-simulation reads, episodes/s.

One small spec built in code (default: 1 LV mesh of ~2000 nodes x 4 tissue
settings x 200 sites, 64 sites per build task, so each subject's last task
holds 8 sites, as in ``specs/default.toml``) is built twice through
:func:`simgen.store.runner.build` on a LocalCluster of single-threaded workers:

- **sharded** (schema version 3): ``u`` and ``activation`` in one shard per
  build task with one inner chunk per site;
- **unsharded** (the layout of version 2): one chunk per build task, laid out
  with :data:`simgen.store.layout.SHARD_RESULTS` set to ``False``.

Reported per layout: build wall time (fastest of ``--repeat``), the store's
bytes on disk; the time to read one simulation (``u[site]`` of a random subject
and site, ``--reads`` of them, median), with the file's pages dropped from the
page cache before each read (``posix_fadvise``: the disk as a first read finds
it) and with the store in the page cache; and learner episodes/s
(:class:`learner.data.episodes.EpisodeDataset`, 1-5 context + 10 target sites
observed on the surface, as ``specs/train-default.toml``; sites drawn from the
whole subject and from 2 build chunks) with the store in the page cache.

Run: ``.venv/bin/python -m bench.store_read [--out DIR]`` (DIR gets store_read.md and store_read.json).
``--publish`` writes the table into the block ``store_read`` of docs/results.md with the command and the machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zarr

import simgen.store.layout as store_module
from bench.common import add_out_argument, add_publish_argument, check_publish, machine_line, publish_out, write_out
from learner.data.episodes import EpisodeDataset, EpisodeSpec
from shared.reader import subject_ids
from simgen.store.runner import build
from simgen.store.spec import BuildSpec, spec_from_mapping

LAYOUTS = {"sharded": True, "unsharded": False}
TISSUE = ["healthy", "scar-anterior-basal", "scar-septal-mid", "scar-lateral-apical"]


def bench_spec(nodes: int, settings: int, sites: int, chunk: int) -> BuildSpec:
    """One procedural LV under ``settings`` tissue settings, ``sites`` sites in build tasks of ``chunk``."""
    return spec_from_mapping(
        {
            "name": "bench-store-read",
            "tissue": TISSUE[:settings],
            "meshes": [{"id": "lv", "source": "lv", "nodes": nodes}],
            "sites": {"count": sites},
            "output": {"chunk_sites": chunk},
        }
    )


def store_bytes(path: Path) -> int:
    """Apparent bytes of every file under ``path``."""
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def drop_cache(path: Path) -> None:
    """Drop ``path``'s clean pages from the page cache (no root needed)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def warm(path: Path) -> None:
    """Read every file under ``path`` once, so that the page cache holds the store."""
    for p in path.rglob("*"):
        if p.is_file():
            p.read_bytes()


def timed_builds(spec: BuildSpec, tmp: Path, workers: int, repeat: int) -> dict[str, dict]:
    """Each layout built ``repeat`` times, alternating (fastest kept); the last store of each is kept."""
    results: dict[str, dict] = {name: {"build_s": float("inf")} for name in LAYOUTS}
    for _ in range(repeat):
        for name, sharded in LAYOUTS.items():
            store = tmp / f"{name}.zarr"
            shutil.rmtree(store, ignore_errors=True)
            store_module.SHARD_RESULTS = sharded  # read by the layout, which the driver writes in this process
            try:
                seconds = build(spec, store, workers=workers).seconds
            finally:
                store_module.SHARD_RESULTS = True
            results[name]["build_s"] = min(results[name]["build_s"], seconds)
            results[name]["store_mb"] = store_bytes(store) / 1e6
    return results


def single_reads(store: Path, reads: int, cold: bool, seed: int = 0) -> float:
    """Median seconds of ``u[site]`` for ``reads`` random subjects and sites (``cold``: file dropped first)."""
    rng = np.random.default_rng(seed)
    root = zarr.open_group(str(store), mode="r")
    arrays = {s: root[f"subjects/{s}/u"] for s in subject_ids(store)}
    ids = sorted(arrays)
    times = []
    for _ in range(reads):
        u = arrays[ids[rng.integers(len(ids))]]
        site = int(rng.integers(u.shape[0]))
        if cold:
            grid = u.shards or u.chunks
            drop_cache(store / u.path / "c" / str(site // grid[0]) / "0" / "0")
        start = time.perf_counter()
        u[site]
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def episodes_per_second(store: Path, chunks_per_episode: int, episodes: int) -> float:
    """Episodes/s of an :class:`EpisodeDataset` over every subject, iterated in this process."""
    spec = EpisodeSpec(context=(1, 5), targets=10, observe="surface", chunks_per_episode=chunks_per_episode)
    ids = subject_ids(store)
    ds = EpisodeDataset(store, ids, spec, seed=0, episodes_per_subject=max(1, episodes // len(ids)))
    next(iter(ds))  # opens the arrays once, as a DataLoader worker does
    start = time.perf_counter()
    n = sum(1 for _ in ds)
    return n / (time.perf_counter() - start)


def run(args) -> dict:
    spec = bench_spec(args.nodes, args.settings, args.sites, args.chunk)
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        results = timed_builds(spec, Path(tmp), args.workers, args.repeat)
        for name, row in results.items():
            store = Path(tmp) / f"{name}.zarr"
            row["read_cold_ms"] = 1e3 * single_reads(store, args.reads, cold=True)
            warm(store)
            row["read_warm_ms"] = 1e3 * single_reads(store, args.reads, cold=False)
            for k in (0, 2):
                row[f"episodes_per_s_chunks_{k}"] = episodes_per_second(store, k, args.episodes)
    return results


def markdown(results: dict, args, seconds: float, load: float) -> str:
    base = results["unsharded"]
    lines = [
        f"Machine: {machine_line()}, Python {platform.python_version()}, "
        f"zarr {zarr.__version__}; 1-minute load average {load:.1f} before the run; {seconds:.0f} s in all.",
        "",
        f"#### Sharded vs unsharded: 1 LV mesh ({args.nodes} nodes) x {args.settings} tissue settings x "
        f"{args.sites} sites, {args.chunk} sites per build task, {args.workers} workers",
        "",
        "| layout | build (s) | store MB | one simulation, cold (ms) | one simulation, cached (ms) "
        "| episodes/s, sites anywhere | episodes/s, 2 chunks |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r['build_s']:.2f} | {r['store_mb']:.0f} | {r['read_cold_ms']:.2f} | "
            f"{r['read_warm_ms']:.2f} | {r['episodes_per_s_chunks_0']:.1f} | {r['episodes_per_s_chunks_2']:.1f} |"
        )
    s = results["sharded"]
    lines += [
        "",
        f"Sharded over unsharded: one simulation {base['read_cold_ms'] / s['read_cold_ms']:.1f}x faster cold, "
        f"{base['read_warm_ms'] / s['read_warm_ms']:.1f}x cached; episodes/s "
        f"{s['episodes_per_s_chunks_0'] / base['episodes_per_s_chunks_0']:.1f}x (sites anywhere), "
        f"{s['episodes_per_s_chunks_2'] / base['episodes_per_s_chunks_2']:.1f}x (2 chunks); "
        f"build time {s['build_s'] / base['build_s']:.2f}x.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, default=2000)
    p.add_argument("--settings", type=int, default=4)
    p.add_argument("--sites", type=int, default=200)
    p.add_argument("--chunk", type=int, default=64)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--repeat", type=int, default=2, help="builds per layout, fastest kept")
    p.add_argument("--reads", type=int, default=200, help="single-simulation reads per layout and cache state")
    p.add_argument("--episodes", type=int, default=64, help="episodes per layout and draw")
    p.add_argument("--tmp", default=None, help="parent folder of the temporary stores")
    add_out_argument(p, "store_read")
    add_publish_argument(p, "store_read")
    args = p.parse_args(argv)
    check_publish(args.publish)
    load, start = os.getloadavg()[0], time.perf_counter()
    results = run(args)
    text = markdown(results, args, time.perf_counter() - start, load)
    print(text)
    publish_out(args.publish, "store_read", text)
    write_out(args.out, "store_read", text, {"args": vars(args) | {"out": str(args.out)}, **results}, indent=None)
    if load > 0.5:
        print(f"warning: load average {load:.1f} at the start: other processes slow these figures", file=sys.stderr)


if __name__ == "__main__":
    main()
