"""Benchmark: does a multigrid preconditioner pay for IMEX's implicit solves at 1k-20k nodes?

IMEX-CG (``simgen/solver/imex_cg.py``) preconditions its solves with the
diagonal (Jacobi). Its iterations grow with the mesh, which is what keeps
its cost above linear. This script solves the SBDF2 system
``B x = b``, ``B = 3/2 M + dt K`` at the default ``dt``, on the procedural LV
at ``--nodes``, once with Jacobi-preconditioned CG and once with CG
preconditioned by one V-cycle of smoothed-aggregation algebraic multigrid
(`pyamg <https://pypi.org/project/pyamg/>`_, MIT; not a dependency of the
project: ``pip install pyamg``), both from a zero guess to a relative residual
of ``1e-4`` for a smooth right-hand side (a random vector smoothed by three
Jacobi-scaled products with ``B``). Per mesh: iterations, the multigrid
hierarchy's levels and operator complexity, the setup time of the hierarchy
and the best-of-``--repeat`` wall time of one solve of each (scipy's CG, one
right-hand side, one thread).

Run::

    .venv/bin/pip install pyamg && OMP_NUM_THREADS=1 .venv/bin/python -m bench.preconditioners
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import cg

from bench.common import best_of, machine_line
from simgen.meshes import get_mesh
from simgen.solver.simulate import SolverConfig, assemble, healthy_fields

TOLERANCE = 1e-4


def sbdf2_matrix(nodes: int) -> tuple[sp.csr_matrix, float, int]:
    """``(B, dt, mesh nodes)`` of SBDF2's implicit system on the procedural LV of about ``nodes`` nodes."""
    mesh = get_mesh("lv", nodes, "tetra")
    assembly = assemble(mesh, healthy_fields(mesh.n_nodes), SolverConfig(integrator="imex"), imex_solve="cg")
    matrix = sp.diags(1.5 * np.asarray(assembly.mass)) + assembly.dt * sp.csr_matrix(assembly.stiffness)
    return sp.csr_matrix(matrix), assembly.dt, mesh.n_nodes


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 5000, 20000])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    try:
        import pyamg
    except ImportError:
        raise SystemExit("this benchmark needs pyamg: .venv/bin/pip install pyamg") from None
    print(f"{machine_line()}, pyamg {pyamg.__version__}\n")
    print(
        "| mesh | nodes | dt | Jacobi-CG iterations | Jacobi-CG solve (ms) | AMG-CG iterations | AMG levels | "
        "operator complexity | AMG setup (ms) | AMG-CG solve (ms) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for nodes in args.nodes:
        matrix, dt, n_nodes = sbdf2_matrix(nodes)
        rhs = smooth_rhs(matrix)
        jacobi = timed_solve(matrix, rhs, sp.diags(1 / matrix.diagonal()), args.repeat)
        start = time.perf_counter()
        hierarchy = pyamg.smoothed_aggregation_solver(matrix, max_coarse=50)
        setup = time.perf_counter() - start
        amg = timed_solve(matrix, rhs, hierarchy.aspreconditioner(cycle="V"), args.repeat)
        print(
            f"| lv {nodes} | {n_nodes} | {dt:.3g} | {jacobi[0]} | {1e3 * jacobi[1]:.2f} | {amg[0]} | "
            f"{len(hierarchy.levels)} | {hierarchy.operator_complexity():.2f} | {1e3 * setup:.1f} | "
            f"{1e3 * amg[1]:.2f} |"
        )


if __name__ == "__main__":
    main()
