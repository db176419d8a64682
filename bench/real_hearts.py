"""Benchmark: what a real heart costs to simulate next to a procedural one, with each time integrator.

For the shipped real meshes (``real:NAME``) at ``--real-nodes``, the
shipped rodero01-lv volume as it is (5,440 nodes, not resampled), and the
procedural LV and BiV at ``--nodes`` (default 1k, 5k, 20k; 2k LV too), each
integrator (forward Euler at its stable step, IMEX SBDF2 at its accuracy step
with each of its solves, a direct factor and conjugate gradients, and
``auto``, the default, which runs Euler or IMEX with the cheaper solve) simulates ``--sites``
sites x 55 frames on one thread, with the default stimulus (10 mm) on every
mesh; RKC2 runs too, at the accuracy step with the
stages the mesh needs. Per mesh and integrator the table gives dt, steps,
the work of one step (matrix entries per node: Euler the operator's, RKC2 the
operator's times its stages, IMEX the factor's, solved once per step, or the
implicit matrix's times the CG products of a solve), CG iterations per solve,
setup and wall time, and the error
against the Euler run of the same mesh (largest activation-time difference as
a share of the activation range, and the smallest correlation of the
activation maps over the sites). Then, measured in this run:

* each real heart's default-integrator wall time over the procedural LV's of
  about the same node count (``--real-nodes``);
* the exponent ``p`` of wall ~ nodes^p of the default integrator on the
  procedural LV and BiV from the smallest to the largest ``--nodes``;
* the default integrator's wall time over Euler's on the 2k procedural LV.

Run::

    .venv/bin/python -m bench.real_hearts --out report/bench            # ~10 min on 2 cores
    .venv/bin/python -m bench.real_hearts --nodes 1000 2000 --quick     # real meshes and small LVs only

``--out DIR`` writes real_hearts.md (the tables) and real_hearts.json (raw numbers); ``--publish``
writes the tables into the block ``real_hearts`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np

from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    growth_exponent,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from shared.mesh import Mesh
from simgen.meshes import get_mesh
from simgen.meshes.io import load_mesh
from simgen.meshes.shipped import REAL_MESHES, REAL_PREFIX, unpacked
from simgen.solver.simulate import Simulator, SolverConfig

#: (integrator, IMEX solve) of each row; the first is the reference.
INTEGRATORS = (("euler", None), ("rkc", None), ("imex", "factor"), ("imex", "cg"), ("auto", None))


def agreement(reference: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """Largest activation-time difference over the activation range (per site, worst site) and the smallest
    correlation of activation maps; NaN (never activated) nodes are left out of both."""
    span = np.nanmax(reference, axis=1) - np.nanmin(reference, axis=1)
    share = float(np.nanmax(np.nanmax(np.abs(other - reference), axis=1) / span))
    ok = np.isfinite(reference) & np.isfinite(other)
    cc = min(float(np.corrcoef(r[k], o[k])[0, 1]) for r, o, k in zip(reference, other, ok))
    return share, cc


def bench(mesh: Mesh, label: str, sites: np.ndarray, args: argparse.Namespace) -> list[tuple[dict, np.ndarray]]:
    """One mesh with each of :data:`INTEGRATORS`: per integrator the row of the table and the activation times.

    The timed runs go round the integrators ``--repeat`` times and each keeps its best, so that a slow
    spell of the machine does not fall on one integrator's runs alone."""
    simulators, setups = [], []
    for integrator, solve in INTEGRATORS:
        t0 = time.perf_counter()
        config = SolverConfig(integrator=integrator)
        simulators.append(Simulator(mesh, config=config, imex_solve=solve))
        setups.append(time.perf_counter() - t0)
        simulators[-1].run(sites[:1])  # compile, and any first-call cost
    walls = np.full((args.repeat, len(simulators)), np.inf)
    results = []
    for repeat in range(args.repeat):
        for i, sim in enumerate(simulators):
            t0 = time.perf_counter()
            result = sim.run(sites, threads=1)
            walls[repeat, i] = time.perf_counter() - t0
            if repeat == 0:
                results.append(result)
    out = []
    for (integrator, solve), sim, setup, wall, result in zip(INTEGRATORS, simulators, setups, walls.min(0), results):
        row = {
            "mesh": label,
            "nodes": mesh.n_nodes,
            "integrator": integrator if solve is None else f"{integrator} {solve}",
            "runs": sim.integrator if sim.imex_solve is None else f"{sim.integrator} {sim.imex_solve}",
            "cg_iterations": sim.cg_iterations,
            "dt": sim.dt,
            "steps": sim.steps_per_frame * sim.config.frames,
            "entries_per_node": sim.entries_per_step / mesh.n_nodes,
            "setup_s": setup,
            "wall_s": float(wall),
        }
        out.append((row, result.activation))
    return out


def meshes(args: argparse.Namespace) -> list[tuple[str, str, Mesh]]:
    """``(kind, label, mesh)``: kind ``"real"`` or the procedural family."""
    out = []
    for name in REAL_MESHES:
        source = f"{REAL_PREFIX}{name}"
        out.append(("real", source, get_mesh(source, args.real_nodes, kind="tetra")))
    with unpacked(f"{REAL_PREFIX}rodero01-lv") as path:  # a CT volume as imaging pipelines give it
        out.append(("real", f"{REAL_PREFIX}rodero01-lv as shipped", load_mesh(path, units="mm")))
    for family in ("lv", "biv"):
        for n in sorted(set(args.nodes) | ({2000} if family == "lv" else set())):
            out.append((family, f"{family} {n}", get_mesh(family, n, kind="tetra")))
    return out


def comparisons(rows: list[dict], args: argparse.Namespace) -> list[str]:
    """Real hearts against procedural ones, growth with node count, default against Euler: Markdown lines."""
    auto = {r["mesh"]: r for r in rows if r["integrator"] == "auto"}
    euler = {r["mesh"]: r for r in rows if r["integrator"] == "euler"}
    lv = [r for r in auto.values() if r["mesh"].startswith("lv ")]
    lines = []
    for r in (r for r in auto.values() if r["mesh"].startswith(REAL_PREFIX)):
        ref = min(lv, key=lambda x: abs(np.log(x["nodes"] / r["nodes"])))
        lines.append(
            f"- {r['mesh']} ({r['nodes']} nodes, {r['runs']}): {r['wall_s'] / ref['wall_s']:.2f}x the wall time of "
            f"the procedural {ref['mesh']} ({ref['nodes']} nodes, {ref['runs']})"
        )
    for family in ("lv", "biv"):
        sized = sorted((r for r in auto.values() if r["mesh"].startswith(family + " ")), key=lambda r: r["nodes"])
        sized = [r for r in sized if r["mesh"] != "lv 2000" or len(args.nodes) == 1]
        if len(sized) >= 2:
            a, b = sized[0], sized[-1]
            nodes = (a["nodes"], b["nodes"])
            p = growth_exponent(nodes, (a["wall_s"], b["wall_s"]))
            e = growth_exponent(nodes, (euler[a["mesh"]]["wall_s"], euler[b["mesh"]]["wall_s"]))
            lines.append(
                f"- {family}: default-integrator wall time ~ nodes^{p:.2f} from {a['nodes']} to {b['nodes']} nodes "
                f"(forward Euler alone: nodes^{e:.2f})"
            )
    if "lv 2000" in auto:
        ratio = auto["lv 2000"]["wall_s"] / euler["lv 2000"]["wall_s"]
        lines.append(f"- lv 2000: default ({auto['lv 2000']['runs']}) / Euler wall time {ratio:.2f}")
    return lines


def markdown(rows: list[dict]) -> str:
    head = (
        "| mesh | nodes | integrator (runs) | dt | steps | entries/node per step | setup (s) | wall (s) "
        "| CG iterations per solve | max abs(activation difference) / range vs Euler | min CC vs Euler |\n"
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    )
    body = "".join(
        f"| {r['mesh']} | {r['nodes']} | {r['integrator']} ({r['runs']}) | {r['dt']:.3g} | {r['steps']} "
        f"| {r['entries_per_node']:.1f} | {r['setup_s']:.2f} | {r['wall_s']:.3f} "
        f"| {'' if r['cg_iterations'] is None else format(r['cg_iterations'], '.1f')} "
        f"| {r.get('share', float('nan')):.4f} | {r.get('cc', float('nan')):.5f} |\n"
        for r in rows
    )
    return head + body


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, nargs="+", default=[1000, 5000, 20000], help="procedural mesh sizes")
    p.add_argument("--real-nodes", type=int, default=1000, help="node target of the real meshes (default 1000)")
    p.add_argument("--sites", type=int, default=8, help="stimulation sites per run (default 8)")
    p.add_argument("--repeat", type=int, default=5, help="timed rounds over the integrators; best kept (default 5)")
    p.add_argument("--quick", action="store_true", help="procedural meshes up to 2k nodes only")
    add_out_argument(p, "real_hearts")
    add_publish_argument(p, "real_hearts")
    args = p.parse_args(argv)
    check_publish(args.publish)
    if args.quick:
        args.nodes = [n for n in args.nodes if n <= 2000] or [1000]
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    rows = []
    for _, label, mesh in meshes(args):
        sites = np.random.default_rng(0).choice(mesh.n_nodes, args.sites, replace=False)
        measured = bench(mesh, label, sites, args)
        reference = measured[0][1]  # Euler's
        for row, activation in measured:
            row["share"], row["cc"] = agreement(reference, activation)
            rows.append(row)
            print(markdown([row]).splitlines()[-1], flush=True)
    total = time.perf_counter() - start
    header = (
        f"Real-heart bench: {machine_line()}, numba {numba.__version__}, one thread, "
        f"{args.sites} sites x 55 frames per run, the default stimulus, best of {args.repeat}; "
        f"total {total:.0f} s; "
        f"1-min load average before the run {load_before:.1f}\n"
    )
    text = header + "\n" + markdown(rows) + "\n" + "\n".join(comparisons(rows, args)) + "\n"
    print(text)
    write_out(args.out, "real_hearts", text, {**machine(), "total_s": total, "rows": rows}, indent=2)
    publish_out(args.publish, "real_hearts", text)


if __name__ == "__main__":
    main()
