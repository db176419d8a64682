"""Benchmark: how build time, memory and training step time grow with mesh size and with sites.

Each point runs in a fresh child process (its peak RSS is the memory column):

* **build vs nodes**: a procedural LV of ~1k, 5k, 20k and 50k nodes, 1 tissue
  setting, 8 sites in one chunk, through the build's own steps: plan (mesh
  generation, sites), store layout, simulator set-up (operator assembly and
  the Lanczos eigenvalue bound), ``Simulator.run(sites, threads=1)`` (the
  compiled kernel loaded beforehand on a small mesh) and
  ``write_chunk`` - one Dask task's work, without the cluster;
* **build vs sites**: the ~2k LV with 16 to 512 sites in one chunk;
* **training step vs nodes**: the mesh hierarchy (5 levels down to ~40 nodes)
  and one metaPNS training episode (forward + backward + Adam) of the model
  and loss of ``specs/train-default.toml`` (3 context sequences of 55 frames
  and the config's targets, decoded frames, posterior targets and context
  stride) on random sequences (timings do not depend on the values), fastest
  of 2 after a warm-up.

The time step shrinks with the mesh spacing (explicit stability), so a
simulation costs about ``nodes^(5/3)`` on these meshes; a training episode
grows about linearly in the nodes. Writes ``scaling.md``, ``scaling.json``
and ``scaling.png`` (log-log).

Run: ``.venv/bin/python -m bench.scaling [--out DIR] [--nodes 1000,5000,20000,50000] [--sites 16,64,256,512]``.
``--publish`` writes the tables into the block ``scaling`` of docs/results.md with the command and the
machine (with ``--train-only``, the block ``scaling.DEVICE``: ``scaling.cuda``); the plot goes to
``--out``, copied by hand to docs/scaling.png.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import add_out_argument, add_publish_argument, check_publish, machine_line, publish_out, write_out

BUILD_SITES = 8
SITES_MESH = 2000
FRAMES = 55


def peak_rss_mb() -> float:
    """This process's peak resident set size (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child_build(nodes: int, sites: int) -> dict:
    """Plan, layout, simulator set-up, run and write of one chunk of ``sites`` sites on an LV of ``nodes``."""
    from build import small_spec  # bench/build.py, next to this file

    from simgen.meshes.ellipsoid import lv_ellipsoid
    from simgen.solver.simulate import Simulator
    from simgen.store.layout import create_layout, write_chunk
    from simgen.store.manifest import make_plan
    from simgen.store.spec import spec_hash, spec_to_dict
    from simgen.store.worker import prepare

    Simulator(lv_ellipsoid(300, "tetra")).run([0], threads=1)  # load the compiled kernel: untimed
    spec = small_spec(nodes, 1, sites, sites)
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "scaling.zarr"
        t0 = time.perf_counter()
        plan = make_plan(spec)
        t1 = time.perf_counter()
        create_layout(store, plan, spec_to_dict(spec), spec_hash(spec))
        subject = plan.subjects[0].id
        t2 = time.perf_counter()
        sim, site_ids, arrays = prepare(str(store), subject, spec.solver)
        t3 = time.perf_counter()
        res = sim.run(site_ids, threads=1)
        t4 = time.perf_counter()
        write_chunk(store, subject, 0, 0, len(site_ids), res.u, res.activation, arrays)
        t5 = time.perf_counter()
        mesh = plan.meshes[plan.subjects[0].mesh_id]
        return {
            "nodes": mesh.n_nodes,
            "sites": len(site_ids),
            "dt": float(sim.dt),
            "steps": spec.solver.frames * sim.steps_per_frame,
            "plan_s": t1 - t0,
            "layout_s": t2 - t1,
            "setup_s": t3 - t2,
            "run_s": t4 - t3,
            "write_s": t5 - t4,
            "s_per_sim": (t4 - t3) / len(site_ids),
            "total_s": t5 - t0,
            "peak_rss_mb": peak_rss_mb(),
        }


def child_train(nodes: int, device: str = "cpu") -> dict:
    """Hierarchy build and one metaPNS training episode on an LV of ``nodes`` (random sequences) on ``device``."""
    import torch

    from learner.config import load_config
    from learner.data.episodes import Episode
    from learner.graph.hierarchy import hierarchy_for_mesh
    from learner.models.surrogate import MetaPNS
    from learner.runtime import tune_allocator
    from learner.train.loss import episode_loss
    from simgen.meshes.ellipsoid import lv_ellipsoid

    tune_allocator()
    torch.set_num_threads(1)  # the documented training set-up: one core per model
    mesh = lv_ellipsoid(nodes, "tetra")
    config = load_config(Path(__file__).resolve().parent.parent / "specs" / "train-default.toml")
    cfg, train = config.model, config.train
    t0 = time.perf_counter()
    hier = hierarchy_for_mesh(mesh, cfg.levels, cfg.coarsest)
    hier_s = time.perf_counter() - t0
    n = hier.graphs[0].num_nodes
    gen = torch.Generator().manual_seed(0)
    k, m = 3, config.data.episodes.targets
    observed = torch.rand(n, generator=gen) < 0.3
    u = torch.rand(k + m, FRAMES, n, generator=gen)
    sites = torch.randperm(n, generator=gen)[: k + m]
    u, observed, sites, hier = u.to(device), observed.to(device), sites.to(device), hier.to(device)
    episode = Episode(
        "lv",
        "lv",
        sites[:k],
        u[:k] * observed,
        observed,
        u[:k],
        sites[k:],
        u[k:],
        torch.arange(FRAMES, dtype=torch.float32),
    )
    torch.manual_seed(0)
    model = MetaPNS(cfg, FRAMES).to(device).train()
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    frames = torch.arange(0, FRAMES, FRAMES // train.loss_frames)[: train.loss_frames]

    def step() -> float:
        t = time.perf_counter()
        terms = episode_loss(
            model, episode, hier, train.lambda1, train.lambda2, 1.0, frames, gen, train.posterior_targets
        )
        opt.zero_grad()
        terms.total.backward()
        opt.step()
        sync()
        return time.perf_counter() - t

    step()  # warm-up
    row = {
        "nodes": n,
        "levels": list(hier.sizes),
        "hierarchy_s": hier_s,
        "step_s": min(step(), step()),
        "peak_rss_mb": peak_rss_mb(),
    }
    if device.startswith("cuda"):
        row["peak_gpu_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return row


def run_child(*args: str) -> dict:
    """One measurement in a fresh interpreter (so peak RSS is its own); its JSON line back."""
    out = subprocess.run([sys.executable, "-m", "bench.scaling", "--child", *args], capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"scaling child {args} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """Markdown table of ``rows`` with (key, header, format) columns."""
    head = "| " + " | ".join(h for _, h, _ in columns) + " |\n|" + "---:|" * len(columns) + "\n"
    body = "".join("| " + " | ".join(format(r[key], fmt) for key, _, fmt in columns) + " |\n" for r in rows)
    return head + body


def slope(rows: list[dict], x: str, y: str) -> float:
    """Least-squares exponent ``p`` of ``y ~ x^p`` over ``rows``."""
    import numpy as np

    return float(np.polyfit(np.log([r[x] for r in rows]), np.log([r[y] for r in rows]), 1)[0])


def plot(nodes: list[dict], sites: list[dict], train: list[dict], path: Path) -> None:
    """Log-log panels: build time and memory vs nodes and vs sites, training step vs nodes."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    ax = axes[0]
    ax.loglog([r["nodes"] for r in nodes], [r["s_per_sim"] for r in nodes], "o-", label="s per simulation")
    ax.loglog([r["nodes"] for r in nodes], [r["peak_rss_mb"] / 1e3 for r in nodes], "s--", label="peak RSS (GB)")
    ax.set(xlabel="mesh nodes", title=f"build, {BUILD_SITES} sites, 1 thread")
    ax = axes[1]
    ax.loglog([r["sites"] for r in sites], [r["run_s"] + r["write_s"] for r in sites], "o-", label="run + write (s)")
    ax.loglog([r["sites"] for r in sites], [r["peak_rss_mb"] / 1e3 for r in sites], "s--", label="peak RSS (GB)")
    ax.set(xlabel="sites in one chunk", title=f"build, ~{SITES_MESH}-node LV, 1 thread")
    ax = axes[2]
    ax.loglog([r["nodes"] for r in train], [r["step_s"] for r in train], "o-", label="s per episode")
    ax.loglog([r["nodes"] for r in train], [r["peak_rss_mb"] / 1e3 for r in train], "s--", label="peak RSS (GB)")
    ax.set(xlabel="mesh nodes", title="metaPNS training episode, 1 thread")
    for ax in axes:
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_out_argument(p, "scaling")
    p.add_argument("--nodes", default="1000,5000,20000,50000")
    p.add_argument("--sites", default="16,64,256,512")
    p.add_argument("--train-only", action="store_true", help="only the training-step rows")
    p.add_argument("--device", default="cpu", help="torch device of the training-step rows (e.g. cuda)")
    p.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    add_publish_argument(p, "scaling")
    args = p.parse_args(argv)
    if args.publish == "scaling" and args.train_only:
        args.publish = f"scaling.{args.device.split(':')[0]}"  # the block of training-only runs on that device
    if args.child:
        kind, *values = args.child
        result = child_build(*map(int, values)) if kind == "build" else child_train(int(values[0]), values[1])
        print(json.dumps(result))
        return
    check_publish(args.publish)
    t0 = time.perf_counter()
    node_list, site_list = [int(v) for v in args.nodes.split(",")], [int(v) for v in args.sites.split(",")]
    nodes, sites, train = [], [], []
    for n in node_list:
        train.append(run_child("train", str(n), args.device))
        print(f"train {train[-1]['nodes']} nodes: {train[-1]['step_s']:.2f} s", file=sys.stderr, flush=True)
    if args.train_only:
        gpu = all("peak_gpu_mb" in r for r in train)
        memory = ("peak_gpu_mb", "peak GPU memory (MB)", ".0f") if gpu else ("peak_rss_mb", "peak RSS (MB)", ".0f")
        columns = [
            ("nodes", "nodes", "d"),
            ("hierarchy_s", "hierarchy (s, host CPU)" if gpu else "hierarchy (s)", ".2f"),
            ("step_s", "s per episode", ".2f"),
            memory,
        ]
        md = (
            f"metaPNS training episode on {args.device}: {machine_line()}; "
            f"total {time.perf_counter() - t0:.0f} s\n\n{table(train, columns)}"
        )
        print(md)
        publish_out(args.publish, "scaling", md)
        write_out(args.out, f"scaling-train-{args.device.split(':')[0]}", md, train, indent=2)
        return
    for n in node_list:
        nodes.append(run_child("build", str(n), str(BUILD_SITES)))
        print(f"build {nodes[-1]['nodes']} nodes: {nodes[-1]['total_s']:.1f} s", file=sys.stderr, flush=True)
    for s in site_list:
        sites.append(run_child("build", str(SITES_MESH), str(s)))
        print(f"build {s} sites: {sites[-1]['total_s']:.1f} s", file=sys.stderr, flush=True)
    build_cols = [
        ("nodes", "nodes", "d"),
        ("sites", "sites", "d"),
        ("dt", "dt", ".4g"),
        ("steps", "steps", "d"),
        ("plan_s", "plan (s)", ".2f"),
        ("layout_s", "layout (s)", ".2f"),
        ("setup_s", "set-up (s)", ".2f"),
        ("run_s", "run (s)", ".2f"),
        ("s_per_sim", "s per sim", ".3f"),
        ("write_s", "write (s)", ".3f"),
        ("peak_rss_mb", "peak RSS (MB)", ".0f"),
    ]
    train_cols = [
        ("nodes", "nodes", "d"),
        ("hierarchy_s", "hierarchy (s)", ".2f"),
        ("step_s", "s per episode", ".2f"),
        ("peak_rss_mb", "peak RSS (MB)", ".0f"),
    ]
    md = (
        f"Scaling bench: {machine_line()}, one thread per measurement; "
        f"total {time.perf_counter() - t0:.0f} s\n\n"
        f"#### Build vs mesh nodes ({BUILD_SITES} sites, one chunk)\n\n{table(nodes, build_cols)}\n"
        f"Time per simulation grows as nodes^{slope(nodes, 'nodes', 's_per_sim'):.2f} "
        f"(steps as nodes^{slope(nodes, 'nodes', 'steps'):.2f}: dt follows the mesh spacing).\n\n"
        f"#### Build vs sites (~{SITES_MESH}-node LV, one chunk)\n\n{table(sites, build_cols)}\n"
        f"Run time grows as sites^{slope(sites, 'sites', 'run_s'):.2f}, peak memory as "
        f"sites^{slope(sites, 'sites', 'peak_rss_mb'):.2f}.\n\n"
        f"#### metaPNS training episode vs mesh nodes\n\n{table(train, train_cols)}\n"
        f"Episode time grows as nodes^{slope(train, 'nodes', 'step_s'):.2f}.\n"
    )
    print(md)
    publish_out(args.publish, "scaling", md)
    if write_out(args.out, "scaling", md, {"build_nodes": nodes, "build_sites": sites, "train": train}, indent=2):
        plot(nodes, sites, train, args.out / "scaling.png")


if __name__ == "__main__":
    main()
