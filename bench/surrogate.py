"""Benchmark: the surrogate's speeds on CPU, next to the simulator's, measured in one run.

* generation: one 55-frame full-mesh sequence for a new stimulation site given
  ``c`` (batch of 1, and per simulation in a batch of 16), against
  ``Simulator.run`` for the same site on the same mesh (one simulation);
* context embedding: q(c | Y) for a set of 1 and of 5 observed sequences;
* both with every ``SplineConv`` on the per-edge path, then on each layer's
  default ("auto": block-sparse CSR on the narrow fine levels), side by side;
* ``--device cuda``: generation, embedding and training on that device (the
  loader stays on the CPU; no simulator or per-edge rows);
* training: one episode (forward + backward + Adam) of the configured size,
  metaPNS and PNS, and the loader's episodes/s (it should outrun training >= 5x);
  the metaPNS episode again in a child process with glibc's default allocator
  (no ``learner.runtime.tune_allocator``), for the allocator's share.

The model is untrained (timings do not depend on the weights); its sizes, the
context stride and the training-episode settings come from ``--config`` (default
``specs/train-default.toml``, the shipped training set-up). Meshes and
sequences come from a store built by ``simgen build`` (default: a 2k-node LV,
55 frames, built here in a temporary folder when ``--store`` is not given).

Run: ``.venv/bin/python -m bench.surrogate [--store PATH] [--config TOML] [--mesh lv] [--out DIR]``.
``--publish`` writes the table (without the goal column) into the block ``surrogate`` of docs/results.md
with the command and the machine (``surrogate.cuda`` with ``--device cuda``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from bench import common
from learner.config import LearnerConfig, load_config
from learner.data.episodes import EpisodeDataset, load_episode
from learner.models.surrogate import PNS, MetaPNS
from learner.nn.spline_conv import SplineConv
from learner.runtime import tune_allocator
from learner.store_view import StoreView
from learner.train.loss import episode_loss

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "specs" / "train-default.toml"
# generation per simulation, as a batch of 16 targets amortises it; embedding per whole context set (1 or 5 shots)
GOALS = {"generate_batch16_ms_per_sim": 50.0, "embed_5_ms": 30.0, "embed_1_ms": 30.0, "loader_over_training": 5.0}


def goal_text(key: str) -> str:
    """The goal column of a row: ``<= x`` for times, ``>= x`` for the loader ratio, empty without a goal."""
    if key not in GOALS:
        return ""
    return f"{'>=' if key == 'loader_over_training' else '<='} {GOALS[key]}"


def best_of(fn, repeat: int) -> float:
    """Fastest wall time of ``repeat`` calls (after one warm-up call), waiting for a GPU to finish."""
    sync = torch.cuda.synchronize if torch.cuda.is_available() else None
    return common.best_of(fn, repeat, warmup=True, sync=sync)[0]


def measure_inference(meta: MetaPNS, hier, ep, repeat: int, device: str) -> dict[str, float]:
    """Generation (1 and 16 sites) and embedding (sets of 5 and 1) times in ms on ``device``."""
    meta, hier = meta.to(device), hier.to(device)
    obs, observed, sites = ep.context_obs.to(device), ep.observed.to(device), ep.target_sites.to(device)
    rows = {}
    with torch.no_grad():
        c = meta.embed(obs, observed, hier).mu
        rows["generate_ms"] = 1e3 * best_of(lambda: meta.generate(sites[:1], hier, c), repeat)
        rows["generate_batch16_ms_per_sim"] = 1e3 * best_of(lambda: meta.generate(sites, hier, c), repeat) / 16
        rows["embed_5_ms"] = 1e3 * best_of(lambda: meta.embed(obs, observed, hier), repeat)  # a 5-shot set
        rows["embed_5_ms_per_sequence"] = rows["embed_5_ms"] / len(obs)
        rows["embed_1_ms"] = 1e3 * best_of(lambda: meta.embed(obs[:1], observed, hier), repeat)
    return rows


def small_store(folder: Path) -> Path:
    """A 2k-node LV x 2 settings x 25 sites store, 55 frames (the default spec's resolution)."""
    from simgen.store import spec_from_mapping
    from simgen.store.runner import build

    spec = spec_from_mapping(
        {
            "meshes": [{"id": "lv", "source": "lv", "nodes": 2000}],
            "tissue": ["healthy", "scar-apex"],
            "sites": {"count": 25},
            "output": {"chunk_sites": 25},
        }
    )
    store = folder / "bench.zarr"
    build(spec, store, workers=2)
    return store


def set_conv_method(model: torch.nn.Module, method: str | None) -> None:
    """Every SplineConv of ``model`` on one evaluation method (None: each layer's "auto" choice)."""
    for layer in model.modules():
        if isinstance(layer, SplineConv):
            layer.inference_method = method or SplineConv.auto_method(layer.in_channels, layer.out_channels, True)


def simulator_seconds(store: Path, subject: str, site: int) -> float:
    """One AP simulation of ``subject`` at ``site`` with the solver that built the store."""
    from shared.reader import read_tissue
    from simgen.solver.simulate import Simulator

    view = StoreView(store)
    mesh = view.mesh(view.mesh_of[subject])
    sim = Simulator(mesh, read_tissue(store, subject))
    return best_of(lambda: sim.run(np.array([site]), threads=1), 2)


def loader_rate(view: StoreView, subjects: list[str], spec, workers: int) -> float:
    """Episodes per second the loader delivers, 3 epochs of 8 episodes per subject: in this process,
    or from ``workers`` processes (a persistent ``DataLoader``, as ``data.workers`` feeds a GPU)."""
    ds = EpisodeDataset(view.store, subjects, spec, seed=0, episodes_per_subject=8)
    if workers == 0:
        passes = (ds for _ in range(3))
    else:
        loader = DataLoader(ds, batch_size=None, num_workers=workers, persistent_workers=True)
        next(iter(loader))  # start the workers outside the timing
        passes = (loader for _ in range(3))
    t0 = time.perf_counter()
    n_loaded = 0
    for epoch, source in enumerate(passes, start=1):
        ds.set_epoch(epoch)  # persistent workers keep their epoch: the same work, other episodes unneeded here
        n_loaded += sum(1 for _ in source)
    return n_loaded / (time.perf_counter() - t0)


def measure_training(
    view: StoreView,
    hier,
    meta: MetaPNS,
    pns: PNS,
    config: LearnerConfig,
    mesh: str,
    device: str = "cpu",
    loader_workers: int = 0,
) -> tuple[dict, float]:
    """Seconds per training episode (metaPNS, PNS) on ``device`` and the loader's episodes/s (CPU)."""
    train = config.train
    subjects = [s for s in view.subjects if view.mesh_of[s] == mesh]
    episodes = list(EpisodeDataset(view.store, subjects, config.data.episodes, seed=0))
    loader_eps = loader_rate(view, subjects, config.data.episodes, loader_workers)
    episodes = [
        dataclasses.replace(
            ep,
            **{
                f.name: getattr(ep, f.name).to(device)
                for f in dataclasses.fields(ep)
                if isinstance(getattr(ep, f.name), torch.Tensor)
            },
        )
        for ep in episodes[:2]
    ]
    hier = hier.to(device)
    g = torch.Generator().manual_seed(0)
    rows = {}
    frames = view.frames
    for name, model in (("metapns", meta), ("pns", pns)):
        model.to(device).train()
        opt = torch.optim.Adam(model.parameters(), 1e-3)
        frames_idx = torch.arange(0, frames, max(frames // train.loss_frames, 1))[: train.loss_frames]

        def step(model=model, opt=opt, frames_idx=frames_idx):
            for episode in episodes:
                terms = episode_loss(
                    model, episode, hier, train.lambda1, train.lambda2, 1.0, frames_idx, g, train.posterior_targets
                )
                opt.zero_grad()
                terms.total.backward()
                opt.step()

        rows[f"train_{name}_s_per_episode"] = best_of(step, 2) / 2
    return rows, loader_eps


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--store", type=Path)
    p.add_argument("--subject", default=None, help="subject id (default: the first on --mesh)")
    p.add_argument("--mesh", default="lv")
    p.add_argument(
        "--config",
        type=Path,
        default=DEFAULT_CONFIG,
        help="training config whose model and episode settings are timed (default: %(default)s)",
    )
    p.add_argument("--repeat", type=int, default=3)
    common.add_out_argument(p, "surrogate")
    p.add_argument(
        "--device", default="cpu", help="another torch device (cuda): generation, embedding and training there"
    )
    p.add_argument(
        "--loader-workers",
        type=int,
        default=0,
        help="loader processes for the loader rate (default 0: in this process)",
    )
    p.add_argument("--train-only", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--no-tune", action="store_true", help=argparse.SUPPRESS)
    common.add_publish_argument(p, "surrogate")
    args = p.parse_args(argv)
    if args.publish == "surrogate" and args.device != "cpu":
        args.publish = f"surrogate.{args.device.split(':')[0]}"  # the block of runs on that device
    common.check_publish(args.publish)
    if not args.no_tune:
        tune_allocator()
    tmp = None
    if args.store is None:
        tmp = tempfile.TemporaryDirectory()
        args.store = small_store(Path(tmp.name))
    view = StoreView(args.store)
    subject = args.subject or next(s for s in view.subjects if view.mesh_of[s] == args.mesh)
    config = load_config(args.config)
    cfg = config.model
    hier = view.hierarchy(view.mesh_of[subject], cfg.levels, cfg.coarsest)
    n_nodes, frames = hier.graphs[0].num_nodes, view.frames
    torch.manual_seed(0)
    meta, pns = MetaPNS(cfg, frames).eval(), PNS(cfg, frames).eval()
    if args.train_only:  # the child process of the allocator comparison
        print(json.dumps(measure_training(view, hier, meta, pns, config, args.mesh)[0]))
        return
    ep = load_episode(view.store, subject, [0, 1, 2, 3, 4], list(range(5, 5 + 16)), "surface")
    on_cpu = args.device == "cpu"
    rows: dict[str, float] = {}
    if on_cpu:  # every SplineConv on the per-edge path first, for the block-sparse path's gain
        set_conv_method(meta, "edges")
        rows.update({f"{k}_edges_only": v for k, v in measure_inference(meta, hier, ep, args.repeat, "cpu").items()})
        set_conv_method(meta, None)
    rows.update(measure_inference(meta, hier, ep, args.repeat, args.device))
    if on_cpu:
        rows["speedup_sparse_conv_generate"] = rows["generate_ms_edges_only"] / rows["generate_ms"]
        rows["speedup_sparse_conv_embed"] = rows["embed_5_ms_edges_only"] / rows["embed_5_ms"]
        rows["simulate_ms"] = 1e3 * simulator_seconds(args.store, subject, int(ep.target_sites[0]))

    train_rows, loader_eps = measure_training(
        view, hier, meta, pns, config, args.mesh, args.device, args.loader_workers
    )
    rows.update(train_rows)
    if on_cpu:
        child = subprocess.run(
            [
                sys.executable,
                "-m",
                "bench.surrogate",
                "--store",
                str(args.store),
                "--subject",
                subject,
                "--mesh",
                args.mesh,
                "--config",
                str(args.config),
                "--train-only",
                "--no-tune",
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        rows["train_metapns_s_per_episode_default_malloc"] = json.loads(child.stdout)["train_metapns_s_per_episode"]
    rows["loader_workers"] = args.loader_workers
    rows["loader_episodes_per_s"] = loader_eps  # always on the CPU
    rows["loader_over_training"] = loader_eps * rows["train_metapns_s_per_episode"]
    if on_cpu:
        rows["speedup_generate_vs_simulate"] = rows["simulate_ms"] / rows["generate_ms"]

    if on_cpu:
        where = f"CPU: {common.machine_line()}, {torch.get_num_threads()} threads"
    else:
        device = torch.cuda.get_device_name(args.device) if args.device.startswith("cuda") else args.device
        where = f"{device}; the loader on the host CPU"
    head = (
        f"# Surrogate speed ({where}, torch {torch.__version__})\n\n"
        f"Mesh `{view.mesh_of[subject]}` ({n_nodes} nodes, hierarchy {hier.sizes}), {frames} frames; "
        f"reference-size model ({sum(p.numel() for p in meta.parameters()):,} parameters).\n\n"
    )
    table = "| quantity | value | goal |\n|---|---|---|\n" + "".join(
        f"| {k} | {v:.3g} | {goal_text(k)} |\n" for k, v in rows.items()
    )
    print(head + table)
    published = "| quantity | value |\n|---|---|\n" + "".join(f"| {k} | {v:.3g} |\n" for k, v in rows.items())
    common.publish_out(args.publish, "surrogate", head.removeprefix("# ") + published)
    if args.out:
        name = "surrogate" if on_cpu else f"surrogate-{args.device.split(':')[0]}"
        summary = {
            "rows": rows,
            "nodes": n_nodes,
            "frames": frames,
            "device": args.device,
            "config": str(args.config),
            "model": config.to_dict()["model"],
        }
        common.write_out(args.out, name, head + table, summary, indent=2)
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
