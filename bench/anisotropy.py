"""Benchmark: the cost of anisotropic conduction and of rule-based fibres against isotropic conduction.

On the procedural LV (tetrahedra) at about ``--nodes`` nodes each (default 1,000, 5,000 and 20,000), per
integrator (Euler, RKC2, IMEX), ``--sites`` pacing sites over the default 55 frames: the wall time of one
simulation run (operator assembly, time step and integration, single-threaded, best of ``--repeat``),
isotropic and with rule-based fibres at ``D_l / D_t = --ratio``, and their ratio; the time step each chose;
and the time of the fibres themselves (two Laplace solves, :func:`simgen.meshes.fibres.ldrb_fibres`).

Anisotropy enters through the stiffness matrix only: the kernels are the same, so the cost differs by the
tensor assembly and by the time step the assembled operator allows (conduction across the fibres is
slower, so ``lambda_max`` and the stable explicit step change).

Run::

    .venv/bin/python -m bench.anisotropy --out report/bench

``--publish`` writes the table into the block ``anisotropy`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from bench.common import add_out_argument, add_publish_argument, best_of, check_publish, machine, publish_out, write_out
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fibres import ldrb_fibres
from simgen.solver.simulate import Simulator, SolverConfig

INTEGRATORS = ("euler", "rkc", "imex")


def measure(nodes: int, sites: int, ratio: float, repeat: int) -> list[dict]:
    """One row per integrator at about ``nodes`` nodes: run times isotropic and anisotropic, steps, fibre time."""
    mesh = get_mesh("lv", nodes, "tetra")
    fibre_s, (fibres, _) = best_of(lambda: ldrb_fibres(mesh), repeat)
    fibred = dataclasses.replace(mesh, fibres=fibres)
    ids = np.linspace(0, mesh.n_nodes - 1, sites).astype(np.int64)
    rows = []
    for integrator in INTEGRATORS:
        row = {"nodes": mesh.n_nodes, "integrator": integrator, "fibres_s": fibre_s}
        for name, m, anisotropy in (("iso", mesh, None), ("aniso", fibred, ratio)):
            config = SolverConfig(integrator=integrator, anisotropy=anisotropy)

            def run(m=m, config=config) -> Simulator:
                sim = Simulator(m, config=config)
                sim.run(ids, threads=1)
                return sim

            seconds, sim = best_of(run, repeat, warmup=True)
            row[f"{name}_s"], row[f"{name}_dt"] = seconds, sim.dt
        rows.append(row)
    return rows


def table(rows: list[dict], sites: int, ratio: float) -> str:
    lines = [
        f"{sites} sites, 55 frames, one thread, D_l / D_t = {ratio:g}; run = assembly + time step + integration.",
        "",
        "| nodes | integrator | isotropic run (s) | dt | anisotropic run (s) | dt | ratio | fibres (s) |",
        "|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['nodes']:,} | {r['integrator']} | {r['iso_s']:.3f} | {r['iso_dt']:.4g} | {r['aniso_s']:.3f} | "
            f"{r['aniso_dt']:.4g} | {r['aniso_s'] / r['iso_s']:.2f} | {r['fibres_s']:.3f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 5000, 20000])
    parser.add_argument("--sites", type=int, default=8)
    parser.add_argument("--ratio", type=float, default=4.0, help="D_l / D_t")
    parser.add_argument("--repeat", type=int, default=2)
    add_out_argument(parser, "anisotropy")
    add_publish_argument(parser, "anisotropy")
    args = parser.parse_args(argv)
    check_publish(args.publish)
    start = time.perf_counter()
    rows = [row for n in args.nodes for row in measure(n, args.sites, args.ratio, args.repeat)]
    markdown = table(rows, args.sites, args.ratio)
    print(markdown)
    print(f"({time.perf_counter() - start:.0f} s)")
    write_out(args.out, "anisotropy", markdown, {"machine": machine(), "rows": rows})
    publish_out(args.publish, "anisotropy", markdown)


if __name__ == "__main__":
    main()
