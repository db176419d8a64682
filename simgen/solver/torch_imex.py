"""The IMEX (SBDF2) steps of :mod:`simgen.solver.imex_kernel` in torch, on any torch device.

Each implicit solve is Jacobi-preconditioned conjugate gradients (CG) on
``B = c M + dt K`` (``c = 1`` for the first, backward-Euler step, ``3/2``
after), all sites as columns of one right-hand side, as in the numba CG kernel
(:mod:`simgen.solver.imex_cg`). ``B`` is applied as ``M (c x - dt A x)`` with
the :class:`~simgen.solver.torch_kernel.TorchKernel`'s operator ``A = -M^{-1} K``
(one sparse product per iteration), so nothing is factored and the memory is
the operator's. The stimulus is the same Dirichlet condition: CG runs on the
free nodes of each column with the patch held at ``u = 1``. Iterations stop
when every column's residual is below :data:`RTOL` of its right-hand side
(checked every :data:`CHECK_EVERY` iterations, one wait for the device each);
the result agrees with numba's to that tolerance, not bitwise.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import NDArray

from shared.errors import InputError
from simgen.solver.cells.ops import cell_rates
from simgen.solver.torch_kernel import TorchKernel, _FrameSink, cpu_threads, tensors

__all__ = ["RTOL", "MAX_ITERATIONS", "run_imex_torch"]

#: CG stops when ``||r|| <= RTOL max(||b||, ||r_0||)`` in every column (float32 reaches about 1e-6).
RTOL = 1e-5
#: CG iterations per solve before giving up (the diffusion matrix's condition number is ``1 + dt lambda_max``).
MAX_ITERATIONS = 1000
#: Iterations between convergence checks (each check waits for the device).
CHECK_EVERY = 4


def run_imex_torch(
    kernel: TorchKernel,
    mass: NDArray[np.float32],
    stim: NDArray[np.bool_],
    counts: tuple[int, int, int],
    params: tuple[np.float32, ...],
    cell: tuple,
    frames: NDArray[np.float32],
    act: NDArray[np.float32],
    threads: int = 1,
) -> None:
    """Integrate an IMEX-Euler step, then SBDF2 steps, of every column of the (N, S) mask ``stim`` (kernel order).

    Arguments as :func:`simgen.solver.imex_kernel.run_imex` in ``kernel``'s
    node order, ``mass`` the lumped mass; ``act`` is (N, S). On the CPU torch
    runs ``threads`` threads meanwhile (its setting is restored afterwards).
    """
    stim_steps, n_steps, out_every = counts
    with cpu_threads(kernel.device, threads):
        dev = kernel.device
        dt, thr = float(params[0]), float(params[1])
        constants = tensors(cell, dev)
        m = torch.from_numpy(np.asarray(mass, np.float32)).reshape(-1, 1).to(dev)
        hold = torch.from_numpy(stim).to(dev)
        free = (~hold).to(torch.float32)
        u = hold.to(torch.float32)
        v = torch.full_like(u, float(params[2]))
        act_t = torch.from_numpy(act).to(dev)
        diagonal = _operator_diagonal(kernel)
        sink = _FrameSink(frames, dev)
        up = vp = fp = gp = None
        for i in range(n_steps):
            f, g = cell_rates(u, v, None, kernel.a, constants)  # the reaction alone
            if i == 0 or i == stim_steps:  # a one-step start wherever the stimulus switches
                scale, rhs, vn, guess = 1.0, m * (u + dt * f), v + dt * g, u
            else:
                scale = 1.5
                rhs = m * (2.0 * u - 0.5 * up + dt * (2.0 * f - fp))
                vn = (4.0 * v - vp + 2.0 * dt * (2.0 * g - gp)) / 3.0
                guess = 2.0 * u - up
            mask = free if i < stim_steps else None
            if mask is not None:
                guess = torch.where(hold, 1.0, guess)
            un = _cg(kernel, m, scale, dt, m * (scale - dt * diagonal), rhs, guess, mask)
            crossed = (u < thr) & (un >= thr) & (act_t < 0.0)
            act_t = torch.where(crossed, i * dt + dt * (thr - u) / (un - u), act_t)
            up, vp, fp, gp = u, v, f, g
            u, v = un, vn
            if (i + 1) % out_every == 0:
                sink.put((i + 1) // out_every - 1, u.index_select(0, kernel.inverse_perm).T)
        sink.close()
        act[...] = act_t.cpu().numpy()


def _operator_diagonal(kernel: TorchKernel) -> torch.Tensor:
    """The diagonal of ``kernel.operator`` as an (N, 1) column."""
    A = kernel.operator.to_sparse_coo().coalesce()
    rows, cols = A.indices()
    on = rows == cols
    diagonal = torch.zeros(A.shape[0], dtype=torch.float32, device=A.device)
    diagonal[rows[on]] = A.values()[on]
    return diagonal.reshape(-1, 1)


def _cg(
    kernel: TorchKernel,
    m: torch.Tensor,
    c: float,
    dt: float,
    jacobi: torch.Tensor,
    rhs: torch.Tensor,
    x: torch.Tensor,
    free: torch.Tensor | None,
) -> torch.Tensor:
    """Solve ``M (c x - dt A x) = rhs`` by Jacobi-preconditioned CG from ``x``; with ``free`` (1 on free nodes),
    only the free nodes change (the others keep ``x``: a Dirichlet condition)."""

    def apply(y: torch.Tensor) -> torch.Tensor:
        return m * (c * y - dt * (kernel.operator @ y))

    def r_norm(y: torch.Tensor) -> torch.Tensor:
        return torch.linalg.vector_norm(y, dim=0)

    x = x.clone()
    r = rhs - apply(x)
    if free is not None:
        r = r * free
    scale = torch.maximum(torch.linalg.vector_norm(rhs if free is None else rhs * free, dim=0), r_norm(r))
    limit = RTOL * scale.clamp_min(1e-30)  # the held nodes' pull counts as right-hand side
    z = r / jacobi
    p = z
    rz = (r * z).sum(0)
    for it in range(MAX_ITERATIONS):
        if it % CHECK_EVERY == 0 and bool((r_norm(r) <= limit).all()):
            return x
        q = apply(p)
        if free is not None:
            q = q * free
        pq = (p * q).sum(0)
        alpha = torch.where(pq > 0, rz / torch.where(pq > 0, pq, 1.0), 0.0)
        x = x + alpha * p
        r = r - alpha * q
        z = r / jacobi
        rz_next = (r * z).sum(0)
        beta = torch.where(rz > 0, rz_next / torch.where(rz > 0, rz, 1.0), 0.0)
        p = z + beta * p
        rz = rz_next
    raise InputError(f"the implicit diffusion solve did not converge in {MAX_ITERATIONS} CG iterations")
