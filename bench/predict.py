"""Benchmark: predictions at the speed of the model. A personalised heart in memory, and the CLI in a fresh process.

On a shipped real heart (``--heart``, default ``real:tof-biv``) meshed at
``--nodes`` (default 1k and 20k), the model (``--model``, default the shipped
``anatomies``) is personalised on 4 sock recordings of the healthy heart, then:

* in memory (:class:`learner.personalized.PersonalizedHeart`): the first
  prediction of one site (it builds the model's operators for the mesh's
  graph), the second one-site prediction (the goal at 1k nodes: 0.2 s), and
  one of 8 sites;
* ``learner predict heart.pt --sites (8 sites) --out prediction.npz`` in a
  fresh process, best of ``--repeat`` wall times (the goal: 3 s at 1k nodes,
  5 s at 20k nodes on 2 cores), and the peak memory the command reports.

Run::

    .venv/bin/python -m bench.predict --out report/bench     # ~40 s on 2 cores (the meshes cached)

Meshes are cached in ``--cache`` (shared with bench/convergence.py).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import add_out_argument, machine, machine_line, write_out
from bench.convergence import cached_mesh, pacing_positions
from learner.observations import Observations
from learner.personalized import personalize
from shared.observation import observe
from shared.sites import nearest_nodes
from simgen.observe import Sock
from simgen.solver.simulate import Simulator

#: The goals: a second one-site call at the smallest resolution, the CLI at the smallest and the largest.
GOAL_SECOND_CALL, GOAL_CLI = 0.2, {1000: 3.0, 20_000: 5.0}


def timings(nodes: int, args: argparse.Namespace, folder: Path) -> dict:
    """One resolution's row (module docstring)."""
    mesh = cached_mesh(args.heart, nodes, args.cache)[0]
    positions = pacing_positions(mesh, 12)
    sites = nearest_nodes(mesh.points, positions, np.inf)  # the node nearest each pacing point
    observed = np.zeros(mesh.n_nodes, bool)
    observed[Sock().indices(mesh)] = True
    truth = Simulator(mesh).run(sites[:4], threads=2)
    obs = observe(truth.u, observed, 0.02, np.random.default_rng(0))
    start = time.perf_counter()
    heart = personalize(args.model, Observations(mesh, sites[:4], obs, observed, truth.times), device="cpu")
    personalise = time.perf_counter() - start
    path = heart.save(folder / f"heart-{nodes}.pt")
    calls = []
    for batch in ([sites[4]], [sites[5]], sites[4:12]):
        start = time.perf_counter()
        heart.predict(batch)
        calls.append(time.perf_counter() - start)
    command = [sys.executable, "-m", "learner", "predict", str(path), "--sites", ",".join(map(str, sites[4:12]))]
    command += ["--out", str(folder / "prediction.npz"), "--device", "cpu"]
    walls, peak = [], float("nan")
    for _ in range(args.repeat):
        start = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        walls.append(time.perf_counter() - start)
        found = re.search(r"peak memory (\d+) MB", " ".join(done.stdout.split()))
        peak = float(found.group(1)) if found else peak
    return {
        "nodes": mesh.n_nodes,
        "working": heart.hierarchy.sizes[0],
        "personalize_s": personalise,
        "first_1_site_s": calls[0],
        "second_1_site_s": calls[1],
        "eight_sites_s": calls[2],
        "cli_8_sites_s": min(walls),
        "cli_peak_mb": peak,
        "target": nodes,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="anatomies", help="a shipped name or a checkpoint")
    parser.add_argument("--heart", default="real:tof-biv")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 20_000])
    parser.add_argument("--repeat", type=int, default=3, help="CLI runs per resolution (best wall time)")
    parser.add_argument("--cache", type=Path, default=Path("report/bench/convergence-meshes"))
    add_out_argument(parser, "predict")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        rows = [timings(n, args, Path(folder)) for n in sorted(args.nodes)]
    lines = [
        f"Machine: {machine_line()}. Model `{args.model}` on {args.heart}, personalised on 4 sock recordings.",
        "",
        "| nodes | working graph | personalise (s) | predict 1 site, first (s) | second (s) | 8 sites (s) "
        "| `learner predict`, 8 sites, fresh process (s) | its peak memory (MB) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['nodes']} | {r['working']} | {r['personalize_s']:.2f} | {r['first_1_site_s']:.3f} "
            f"| {r['second_1_site_s']:.3f} | {r['eight_sites_s']:.3f} | {r['cli_8_sites_s']:.2f} "
            f"| {r['cli_peak_mb']:.0f} |"
        )
    first = rows[0]
    goals = [
        f"second one-site call at {first['nodes']} nodes {first['second_1_site_s']:.3f} s (goal {GOAL_SECOND_CALL} s)"
    ]
    goals += [
        f"CLI at {r['nodes']} nodes {r['cli_8_sites_s']:.2f} s (goal {GOAL_CLI[r['target']]:g} s)"
        for r in rows
        if r["target"] in GOAL_CLI
    ]
    text = "\n".join([*lines, "", "; ".join(goals) + "."])
    print(text)
    write_out(args.out, "predict", text + "\n", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
