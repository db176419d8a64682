"""Benchmark: how IMEX-CG's cost grows with the mesh, and whether a multigrid preconditioner would pay.

IMEX-CG (``simgen/solver/imex_cg.py``) preconditions its solves with the
diagonal (Jacobi). Its iterations grow with the mesh, which is what keeps
its cost above linear. Two tables:

* **Growth.** The IMEX-CG solver itself on the procedural LV at ``--nodes``:
  ``--sites`` sites x 55 frames on one thread with an 8 mm stimulus (as in
  ``bench.real_hearts``), best of ``--solver-repeat``. Per mesh: steps, CG
  iterations per solve, wall time, wall time per node and per node and CG
  iteration, and the exponent ``p`` of wall ~ nodes^p from the previous size.
* **Preconditioners.** The SBDF2 system ``B x = b``, ``B = 3/2 M + dt K``
  at the default ``dt`` on the same meshes, solved once with Jacobi-preconditioned
  CG and once with CG preconditioned by one V-cycle of smoothed-aggregation
  algebraic multigrid (`pyamg <https://pypi.org/project/pyamg/>`_, MIT; not a
  dependency of the project: ``pip install pyamg``; the table is left out
  without it), both from a zero guess to a relative residual of ``1e-4`` for a
  smooth right-hand side (a random vector smoothed by three Jacobi-scaled
  products with ``B``). Per mesh: iterations, the multigrid hierarchy's levels
  and operator complexity, its setup time and the best-of-``--repeat`` wall
  time of one solve of each (scipy's CG, one right-hand side, one thread).

Run::

    .venv/bin/pip install pyamg && OMP_NUM_THREADS=1 .venv/bin/python -m bench.preconditioners   # ~4 min

``--out DIR`` writes preconditioners.md (the tables) and preconditioners.json (raw numbers);
``--publish`` writes the tables into the block ``preconditioners`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import cg

from bench.common import (
    add_out_argument,
    add_publish_argument,
    best_of,
    check_publish,
    growth_exponent,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from shared.mesh import Mesh
from simgen.meshes import get_mesh
from simgen.solver.simulate import Simulator, SolverConfig, assemble, healthy_fields

TOLERANCE = 1e-4


def sbdf2_matrix(mesh: Mesh) -> tuple[sp.csr_matrix, float]:
    """``(B, dt)`` of SBDF2's implicit system on ``mesh``."""
    assembly = assemble(mesh, healthy_fields(mesh.n_nodes), SolverConfig(integrator="imex"), imex_solve="cg")
    matrix = sp.diags(1.5 * np.asarray(assembly.mass)) + assembly.dt * sp.csr_matrix(assembly.stiffness)
    return sp.csr_matrix(matrix), assembly.dt


def smooth_rhs(matrix: sp.csr_matrix, seed: int = 0) -> np.ndarray:
    """A random vector smoothed by three Jacobi-scaled products with ``matrix``."""
    rhs = np.random.default_rng(seed).standard_normal(matrix.shape[0])
    for _ in range(3):
        rhs = matrix @ rhs / matrix.diagonal()
    return rhs


def timed_solve(matrix: sp.csr_matrix, rhs: np.ndarray, preconditioner, repeat: int) -> tuple[int, float]:
    """``(iterations, best wall seconds)`` of CG to :data:`TOLERANCE` from a zero guess."""

    def solve() -> int:
        count = [0]
        _, info = cg(
            matrix, rhs, rtol=TOLERANCE, M=preconditioner, callback=lambda _: count.__setitem__(0, count[0] + 1)
        )
        if info != 0:
            raise RuntimeError(f"CG did not converge (info {info})")
        return count[0]

    best, iterations = best_of(solve, repeat)
    return iterations, best


def growth_row(mesh: Mesh, sites: int, repeat: int, warmup: bool) -> dict:
    """One IMEX-CG run of ``sites`` random sites on ``mesh``: steps, CG iterations per solve, best wall time
    (``warmup``: one untimed run first, which loads the compiled kernel)."""
    config = SolverConfig(integrator="imex")
    sim = Simulator(mesh, config=config, imex_solve="cg")
    chosen = np.random.default_rng(0).choice(mesh.n_nodes, sites, replace=False)
    wall, _ = best_of(lambda: sim.run(chosen, threads=1), repeat, warmup=warmup)
    iterations, steps = float(sim.cg_iterations), sim.steps_per_frame * sim.config.frames
    return {
        "nodes": mesh.n_nodes,
        "dt": sim.dt,
        "steps": steps,
        "cg_iterations": iterations,
        "wall_s": wall,
        "us_per_node": 1e6 * wall / mesh.n_nodes,
        "ns_per_node_iteration": 1e9 * wall / (mesh.n_nodes * steps * iterations),
    }


def growth_table(rows: list[dict], sites: int) -> str:
    """The growth rows as Markdown, with the exponent from each size to the next."""
    out = [
        f"IMEX-CG, {sites} sites x 55 frames, one thread, the default stimulus (10 mm):",
        "",
        "| mesh | nodes | dt | steps | CG iterations per solve | wall (s) | wall per node (us) | "
        "per node and CG iteration (ns) | exponent from the previous size |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    previous = None
    for row in rows:
        exponent = ""
        if previous is not None:
            exponent = f"{growth_exponent((previous['nodes'], row['nodes']), (previous['wall_s'], row['wall_s'])):.2f}"
        out.append(
            f"| lv {row['target']} | {row['nodes']} | {row['dt']:.3g} | {row['steps']} | {row['cg_iterations']:.1f} | "
            f"{row['wall_s']:.3f} | {row['us_per_node']:.1f} | {row['ns_per_node_iteration']:.3f} | {exponent} |"
        )
        previous = row
    first, last = rows[0], rows[-1]
    overall = growth_exponent((first["nodes"], last["nodes"]), (first["wall_s"], last["wall_s"]))
    out += ["", f"- IMEX-CG wall time ~ nodes^{overall:.2f} from {first['nodes']} to {last['nodes']} nodes"]
    return "\n".join(out)


def amg_rows(meshes: list[tuple[int, Mesh]], repeat: int) -> list[dict] | None:
    """Jacobi- against multigrid-preconditioned CG on each mesh's SBDF2 system; None without pyamg."""
    try:
        import pyamg
    except ImportError:
        return None
    rows = []
    for target, mesh in meshes:
        matrix, dt = sbdf2_matrix(mesh)
        rhs = smooth_rhs(matrix)
        jacobi = timed_solve(matrix, rhs, sp.diags(1 / matrix.diagonal()), repeat)
        start = time.perf_counter()
        hierarchy = pyamg.smoothed_aggregation_solver(matrix, max_coarse=50)
        setup = time.perf_counter() - start
        amg = timed_solve(matrix, rhs, hierarchy.aspreconditioner(cycle="V"), repeat)
        rows.append(
            {
                "target": target,
                "nodes": mesh.n_nodes,
                "dt": dt,
                "jacobi_iterations": jacobi[0],
                "jacobi_ms": 1e3 * jacobi[1],
                "amg_iterations": amg[0],
                "amg_levels": len(hierarchy.levels),
                "operator_complexity": hierarchy.operator_complexity(),
                "amg_setup_ms": 1e3 * setup,
                "amg_ms": 1e3 * amg[1],
                "pyamg": pyamg.__version__,
            }
        )
    return rows


def amg_table(rows: list[dict] | None) -> str:
    """The preconditioner rows as Markdown (a line saying how to get them without pyamg)."""
    if rows is None:
        return "Preconditioners: left out (pyamg is not installed: .venv/bin/pip install pyamg)."
    out = [
        f"Preconditioners (pyamg {rows[0]['pyamg']}), one solve of B x = b from a zero guess to a relative "
        f"residual of {TOLERANCE:g}:",
        "",
        "| mesh | nodes | dt | Jacobi-CG iterations | Jacobi-CG solve (ms) | AMG-CG iterations | AMG levels | "
        "operator complexity | AMG setup (ms) | AMG-CG solve (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        out.append(
            f"| lv {r['target']} | {r['nodes']} | {r['dt']:.3g} | {r['jacobi_iterations']} | {r['jacobi_ms']:.2f} | "
            f"{r['amg_iterations']} | {r['amg_levels']} | {r['operator_complexity']:.2f} | "
            f"{r['amg_setup_ms']:.1f} | {r['amg_ms']:.2f} |"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 5000, 20000, 50000, 100000])
    parser.add_argument("--sites", type=int, default=8, help="stimulation sites of a growth run (default 8)")
    parser.add_argument("--solver-repeat", type=int, default=2, help="timed growth runs; best kept (default 2)")
    parser.add_argument("--repeat", type=int, default=5, help="timed solves per preconditioner; best kept (default 5)")
    add_out_argument(parser, "preconditioners")
    add_publish_argument(parser, "preconditioners")
    args = parser.parse_args(argv)
    check_publish(args.publish)
    start = time.perf_counter()
    meshes = [(n, get_mesh("lv", n, kind="tetra")) for n in sorted(args.nodes)]
    growth = []
    for i, (target, mesh) in enumerate(meshes):
        growth.append({"target": target, **growth_row(mesh, args.sites, args.solver_repeat, warmup=i == 0)})
        print(f"lv {target}: {growth[-1]['wall_s']:.3f} s", flush=True)
    amg = amg_rows(meshes, args.repeat)
    total = time.perf_counter() - start
    header = f"Preconditioner bench: {machine_line()}, numba {numba.__version__}; total {total:.0f} s"
    text = "\n\n".join([header, growth_table(growth, args.sites), amg_table(amg)]) + "\n"
    print(text)
    write_out(args.out, "preconditioners", text, {**machine(), "total_s": total, "growth": growth, "amg": amg})
    publish_out(args.publish, "preconditioners", text)


if __name__ == "__main__":
    main()
