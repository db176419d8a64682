"""Explicit time-step limits.

Forward Euler on ``du/dt = A u + f(u, v)`` is stable while ``dt`` times the
largest magnitude of the linearised operator stays below 2. The diffusion
part contributes ``lambda_max(M^{-1} K)``; the reaction adds at most the cell
model's ``max_rate`` (for Aliev-Panfilov ``k``: the cubic's slope on [0, 1] is
bounded by ``k (1 - a) < k``), called ``rate`` below. The RKC2
integrator (:mod:`simgen.solver.rkc_kernel`) runs at the accuracy step with as
many stages as that stiffness needs. The IMEX integrator
(:mod:`simgen.solver.imex_kernel`) has no stability limit from diffusion: its
step :data:`DT_IMEX` is set by accuracy alone, and :func:`cheaper_integrator`
says which of it and forward Euler costs less on a mesh.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from shared.errors import TimeStepError
from simgen.solver.rkc_kernel import stability_bound

__all__ = [
    "largest_eigenvalue",
    "stability_limit",
    "choose_time_step",
    "rkc_stages",
    "choose_rkc_step",
    "reaction_limit",
    "choose_imex_step",
    "factor_entry_cost",
    "cg_iterations",
    "factor_solve_cost",
    "cg_solve_cost",
    "cheaper_integrator",
]

#: Largest time step used for accuracy of the Aliev-Panfilov reaction (time units; a cell model's
#: ``dt_accuracy``).
DT_ACCURACY = 0.05
#: Fraction of the stability limit used by the automatic time step.
SAFETY = 0.8
#: The IMEX (SBDF2) step (time units): activation times within 2% of the activation range of a converged
#: forward-Euler reference on the meshes of tests/simgen/solver/test_imex.py (docs/solver-backends.md).
DT_IMEX = 0.05
#: The cost model of ``auto``, in units of one multiply-add with an operator entry in the Euler kernel: the
#: work per node of the reaction (Euler), of the explicit terms (IMEX, once a step) and of the vector
#: updates of one CG iteration. Fitted to bench/real_hearts.py (8 sites, one thread, 2-core AMD EPYC VM):
#: Euler 3.5-4.5 ns per node, site and step at 11-13 entries per node; an IMEX factor entry 0.6 Euler
#: entries while the factor fits in about 1 MB, 1.2 at 10 MB, 1.7 at 80 MB (:func:`factor_entry_cost`).
EULER_NODE_COST = 8.0
IMEX_NODE_COST = 14.0
CG_NODE_COST = 4.0


def largest_eigenvalue(A: sp.csr_matrix, mass: np.ndarray) -> float:
    """``lambda_max(-A)`` for ``A = -M^{-1} K`` via the symmetric form ``M^{1/2} A M^{-1/2}``."""
    s = np.sqrt(mass)
    sym = -(sp.diags(s) @ A @ sp.diags(1.0 / s))
    sym = 0.5 * (sym + sym.T)
    if sym.shape[0] < 50:
        return float(np.linalg.eigvalsh(sym.toarray())[-1])
    try:
        return float(spla.eigsh(sym, k=1, which="LA", tol=1e-4, return_eigenvectors=False)[0])
    except spla.ArpackNoConvergence:  # Gershgorin: a safe upper bound
        return float(np.abs(sym).sum(axis=1).max())


def stability_limit(lam_max: float, rate: float) -> float:
    """Largest stable forward-Euler step for diffusion eigenvalue ``lam_max`` and reaction rate ``rate``."""
    return 2.0 / (lam_max + rate)


def choose_time_step(
    lam_max: float, rate: float, dt: float | None, output_interval: float, accuracy: float = DT_ACCURACY
) -> tuple[float, int]:
    """The time step and the number of steps per output frame.

    With ``dt=None`` the step is ``min(SAFETY * limit, accuracy)``, shrunk so
    that a whole number of steps fits one output interval. A user ``dt`` above
    the limit raises :class:`TimeStepError` quoting the limit.
    """
    limit = stability_limit(lam_max, rate)
    if dt is not None:
        if not np.isfinite(dt) or dt <= 0:
            raise TimeStepError(f"time step dt={dt} must be finite and > 0")
        if dt >= limit:
            raise TimeStepError(
                f"time step dt={dt:g} is unstable: the explicit limit for this mesh and diffusivity is "
                f"{limit:.4g} (2 / (lambda_max {lam_max:.4g} + reaction rate {rate:g})); use dt < {limit:.4g} or "
                "leave it automatic"
            )
        target = dt
    else:
        target = min(SAFETY * limit, accuracy)
    return _fit(target, output_interval)


def rkc_stages(dt: float, lam_max: float, rate: float) -> int:
    """Fewest RKC2 stages (at least 2) whose stability bound covers ``dt (lam_max + rate) / SAFETY``."""
    need = dt * (lam_max + rate) / SAFETY
    s = 2
    while stability_bound(s) < need:
        s += 1
    return s


def choose_rkc_step(
    lam_max: float, rate: float, dt: float | None, output_interval: float, accuracy: float = DT_ACCURACY
) -> tuple[float, int, int]:
    """The RKC2 time step, steps per output frame and stages.

    The step is ``dt`` (``None``: ``accuracy``), shrunk so that a whole
    number of steps fits one output interval; any stiffness is then covered by
    stages (:func:`rkc_stages`), so a ``dt`` above the forward-Euler limit is allowed.
    """
    if dt is not None and (not np.isfinite(dt) or dt <= 0):
        raise TimeStepError(f"time step dt={dt} must be finite and > 0")
    dt, steps = _fit(accuracy if dt is None else dt, output_interval)
    return dt, steps, rkc_stages(dt, lam_max, rate)


def reaction_limit(rate: float) -> float:
    """Largest stable IMEX step for the explicit reaction: SBDF2's explicit part is stable on ``y' = -r y``
    for ``dt r < 2/3``, and the reaction's rates are at most ``rate`` in magnitude."""
    return 2.0 / (3.0 * rate)


def choose_imex_step(
    dt: float | None, rate: float, output_interval: float, accuracy: float = DT_IMEX
) -> tuple[float, int]:
    """The IMEX step fitted to whole steps per output interval, and their number: ``dt``, or with ``None``
    ``accuracy`` (at most ``SAFETY`` times :func:`reaction_limit`).

    No diffusion limit applies; a ``dt`` at or above :func:`reaction_limit`
    raises :class:`TimeStepError` quoting it.
    """
    if dt is not None and (not np.isfinite(dt) or dt <= 0):
        raise TimeStepError(f"time step dt={dt} must be finite and > 0")
    limit = reaction_limit(rate)
    if dt is not None and dt >= limit:
        raise TimeStepError(
            f"time step dt={dt:g} is unstable for the reaction, which the IMEX integrator takes explicitly: "
            f"use dt < {limit:.4g} (2 / (3 x reaction rate {rate:g})) or leave it automatic"
        )
    return _fit(min(accuracy, SAFETY * limit) if dt is None else dt, output_interval)


def cg_iterations(dt: float, stiffness_diagonal: np.ndarray, mass: np.ndarray) -> float:
    """Estimated Jacobi-CG iterations of one IMEX solve: ``4.2 sqrt(1 + q) - 1.6``, ``q`` the 90th
    percentile over the nodes of ``dt K_ii / (3/2 M_i)``, how far diffusion outweighs the mass on the
    diagonal of the implicit matrix (the condition number of the bulk of the mesh, where a few slivers
    only add a few iterations). Fitted to the means measured by bench/real_hearts.py on the procedural
    LV (4.0 at 1,000 nodes, 9.9 at 20,000); the resampled real BiV meshes take about one more, a
    slivered CT volume about one less."""
    ratio = dt * np.asarray(stiffness_diagonal, float) / (1.5 * np.asarray(mass, float))
    return max(1.0, 4.2 * float(np.sqrt(1.0 + np.percentile(ratio, 90))) - 1.6)


def factor_entry_cost(factor_nnz: int) -> float:
    """What one factor entry of an IMEX solve costs in Euler operator entries: 0.6 for a factor of up to 1 MB
    (12 bytes an entry), growing by 0.55 per tenfold size as the factor leaves the caches, at most 1.8."""
    megabytes = 12.0 * factor_nnz / 1e6
    return float(np.clip(0.6 + 0.55 * np.log10(max(megabytes, 1e-9)), 0.6, 1.8))


def factor_solve_cost(factor_nnz: int) -> float:
    """Work of one IMEX solve with a direct factor of ``factor_nnz`` entries, in Euler operator entries."""
    return factor_entry_cost(factor_nnz) * factor_nnz


def cg_solve_cost(iterations: float, implicit_nnz: int, nodes: int) -> float:
    """Work of one IMEX solve by CG, in Euler operator entries: ``iterations`` (:func:`cg_iterations`) and
    the first guess's residual, each a product with the implicit matrix (``implicit_nnz`` entries) and
    :data:`CG_NODE_COST` per node of vector updates."""
    return (iterations + 1.0) * (implicit_nnz + CG_NODE_COST * nodes)


def cheaper_integrator(euler_steps: int, euler_nnz: int, imex_steps: int, solve_cost: float, nodes: int) -> str:
    """``"euler"`` or ``"imex"``: the smaller estimated work for the same simulated time.

    Euler costs ``euler_steps`` products with the operator (``euler_nnz``
    entries, diagonal included) plus its reaction; IMEX ``imex_steps`` solves
    of ``solve_cost`` each (:func:`factor_solve_cost` or :func:`cg_solve_cost`)
    plus its explicit terms; per node :data:`EULER_NODE_COST` and :data:`IMEX_NODE_COST`.
    """
    euler = euler_steps * (euler_nnz + EULER_NODE_COST * nodes)
    imex = imex_steps * (solve_cost + IMEX_NODE_COST * nodes)
    return "imex" if imex < euler else "euler"


def _fit(target: float, output_interval: float) -> tuple[float, int]:
    """The largest step <= ``target`` that fits a whole number of times into ``output_interval``, and that number."""
    steps = max(1, int(np.ceil(output_interval / target - 1e-9)))
    return output_interval / steps, steps
