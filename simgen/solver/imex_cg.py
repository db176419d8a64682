"""The IMEX (SBDF2) steps of :mod:`simgen.solver.imex_kernel` with conjugate-gradient solves: no factor.

Each implicit solve ``B u = rhs``, ``B = c M + dt K`` (``c = 1`` for the
restarting IMEX-Euler steps, ``3/2`` after), runs Jacobi-preconditioned
conjugate gradients (CG) on ``B`` itself, every site a column of one block,
float32, from the extrapolated guess ``2 u_n - u_{n-1}`` (``u_n`` at a
restart). An iteration costs one product with ``B`` (the mesh's pattern:
11-13 entries a node on tetrahedra) and a few vector updates, so the work and
memory of a step grow linearly with the mesh, where a direct factor's fill
grows faster (62 entries a node on a 1,000-node LV, 346 at 20,000). The
iterations a solve needs grow with ``dt`` times the operator's largest
eigenvalue (4.0 a solve on a 1,000-node LV, 9.9 at 20,000;
:func:`simgen.solver.timestep.cg_iterations`); Jacobi scaling keeps isolated
slivers from adding many. :class:`~simgen.solver.simulate.Simulator` runs
these solves where they cost less than the factor's
(:func:`simgen.solver.timestep.cheaper_solve`).

The stimulus is the factor kernel's Dirichlet condition, here directly: CG
runs on each column's free nodes, its residual and search direction zero on
the patch, where ``u`` is held at exactly 1.

Each column stops on its own, when ``r^T D^{-1} r <= TOL^2 d^T D^{-1} d + FLOOR``
(``D`` the diagonal of ``B``, ``d = b - c M u_n`` the step's change of the
right-hand side, on the free nodes): the solver's error per step is a share
of the step's change, so it falls with ``dt`` like the time-stepping error and
SBDF2 keeps its second order. A stopped column no longer changes, and every
column adds in a fixed order, so a column's result depends neither on the
other columns of its block nor on the block width or the threads: runs are
bitwise reproducible. They agree with the factor solves to the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from numpy.typing import NDArray

from simgen.solver.imex_kernel import _STRICT, _explicit, _output, _record, each_block, padded_blocks
from simgen.solver.simd import LANES, vfma, vload, vsplat, vstore

__all__ = ["TOL", "FLOOR", "MAX_ITERATIONS", "Implicit", "implicit_matrices", "run_imex_cg"]

#: Each column's CG stops when its preconditioned residual norm is below TOL times that of the step's change
#: (``b - c M u_n``), so the solver's error shrinks with ``dt`` as the time-stepping error does.
TOL = 1e-4
#: Iterations of one solve before the kernel gives up (and reports the column as unconverged).
MAX_ITERATIONS = 500
#: Absolute floor of the stopping bound on ``r^T D^{-1} r``: far above float32's smallest normal
#: (1.2e-38), far below any change of ``u`` that shows.
FLOOR = np.float32(1e-24)


@dataclass(frozen=True)
class Implicit:
    """The implicit matrices ``B = c M + dt K`` for CG: their shared off-diagonal (float32 CSR, ``dt K_ij``)
    and each one's diagonal, and the lumped mass; in the caller's node order."""

    indptr: NDArray[np.int64]
    indices: NDArray[np.int64]
    offdiagonal: NDArray[np.float32]
    step_diagonal: NDArray[np.float32]
    start_diagonal: NDArray[np.float32]
    mass: NDArray[np.float32]

    @property
    def nnz(self) -> int:
        """Stored entries of ``B``, diagonal included: the multiply-adds of one product per column."""
        return len(self.offdiagonal) + len(self.mass)


def implicit_matrices(
    stiffness: sp.spmatrix, mass: NDArray[np.float64], dt: float, order: NDArray[np.int64]
) -> Implicit:
    """:class:`Implicit` of ``K`` (stiffness) and ``mass`` (lumped) for SBDF2 steps of ``dt``, rows in
    ``order`` (``order[i]``: the mesh node of row ``i``)."""
    mass = np.asarray(mass, float)[order]
    K = sp.csr_matrix(stiffness)[order][:, order]
    diagonal = dt * K.diagonal()
    off = sp.csr_matrix(dt * K - sp.diags(diagonal))
    off.eliminate_zeros()
    off.sort_indices()
    return Implicit(
        off.indptr.astype(np.int64),
        off.indices.astype(np.int64),
        off.data.astype(np.float32),
        (1.5 * mass + diagonal).astype(np.float32),
        (mass + diagonal).astype(np.float32),
        mass.astype(np.float32),
    )


@njit(inline="always", **_STRICT)
def _product(ptr, idx, off, diagonal, p, q, free, holding, pq):  # pragma: no cover - compiled
    """``q = B p`` (zero on held rows while ``holding``) and ``pq += p * q`` per column, LANES columns at a time."""
    n, s = p.shape
    for i in range(n):
        start, end = ptr[i], ptr[i + 1]
        d = vsplat(diagonal[i])
        for c in range(0, s, LANES):
            o = i * s + c
            a0 = d * vload(p, o)
            a1 = vsplat(np.float32(0.0))
            e = start
            while e + 2 <= end:
                a0 = vfma(vsplat(off[e]), vload(p, idx[e] * s + c), a0)
                a1 = vfma(vsplat(off[e + 1]), vload(p, idx[e + 1] * s + c), a1)
                e += 2
            if e < end:
                a0 = vfma(vsplat(off[e]), vload(p, idx[e] * s + c), a0)
            qi = a0 + a1
            if holding:
                qi = qi * vload(free, o)
            vstore(q, o, qi)
            vstore(pq, c, vfma(vload(p, o), qi, vload(pq, c)))


@njit(inline="always", **_STRICT)
def _update(x, r, p, q, inverse_diagonal, alpha, rz):  # pragma: no cover - compiled
    """``x += alpha p``, ``r -= alpha q`` per column; ``rz = r^T D^{-1} r`` of the new residual."""
    n, s = x.shape
    rz[:] = np.float32(0.0)
    for i in range(n):
        di = vsplat(inverse_diagonal[i])
        for c in range(0, s, LANES):
            o = i * s + c
            al = vload(alpha, c)
            vstore(x, o, vfma(al, vload(p, o), vload(x, o)))
            ri = vfma(-al, vload(q, o), vload(r, o))
            vstore(r, o, ri)
            vstore(rz, c, vfma(ri * di, ri, vload(rz, c)))


@njit(inline="always", **_STRICT)
def _direction(r, p, inverse_diagonal, beta):  # pragma: no cover - compiled
    """``p = D^{-1} r + beta p`` per column."""
    n, s = r.shape
    for i in range(n):
        di = vsplat(inverse_diagonal[i])
        for c in range(0, s, LANES):
            o = i * s + c
            vstore(p, o, vfma(vload(beta, c), vload(p, o), vload(r, o) * di))


@njit(inline="always", **_STRICT)
def _change(b, u, mass, scale, change):  # pragma: no cover - compiled
    """``change = b - scale M u``: what the step asks of ``B u_{n+1}`` beyond ``u_n``'s mass term, O(dt)."""
    n, s = u.shape
    vscale = vsplat(scale)
    for i in range(n):
        mi = vsplat(mass[i])
        for c in range(0, s, LANES):
            o = i * s + c
            vstore(change, o, vload(b, o) - vscale * mi * vload(u, o))


@njit(inline="always", **_STRICT)
def _cg(ptr, idx, off, diagonal, inverse_diagonal, x, b, change, free, holding, tol2, max_iterations, work):  # noqa
    """Solve ``B x = b`` for every column (``x`` holds the guess, held rows already 1); the iterations run.

    Each column stops when ``r^T D^{-1} r <= tol2 d^T D^{-1} d + FLOOR``, ``d`` its column of ``change``
    (free rows). ``work = (r, p, q)`` (N, S) and ``(pq, rz, bz, alpha, beta, limit)`` (S,) scratch.
    """
    r, p, q, pq, rz, bz, alpha, beta, limit = work
    n, s = x.shape
    zero = np.float32(0.0)
    _product(ptr, idx, off, diagonal, x, q, free, holding, pq)  # q = B x (pq is reset before it counts)
    rz[:] = zero
    bz[:] = zero
    for i in range(n):
        di = vsplat(inverse_diagonal[i])
        for c in range(0, s, LANES):
            o = i * s + c
            bi = vload(b, o)
            if holding:
                bi = bi * vload(free, o)
            ri = bi - vload(q, o)
            vstore(r, o, ri)
            zi = ri * di
            vstore(p, o, zi)
            vstore(rz, c, vfma(zi, ri, vload(rz, c)))
            ci = vload(change, o)
            if holding:
                ci = ci * vload(free, o)
            vstore(bz, c, vfma(ci * di, ci, vload(bz, c)))
    for c in range(s):
        limit[c] = tol2 * bz[c] + FLOOR  # a column at rest stops before its norms underflow
    done = 0
    while done < max_iterations:
        active = False
        for c in range(s):
            if rz[c] > limit[c]:
                active = True
        if not active:
            break
        pq[:] = zero
        _product(ptr, idx, off, diagonal, p, q, free, holding, pq)
        for c in range(s):
            if rz[c] > limit[c] and not pq[c] > zero:  # p^T B p underflowed: nothing left to reduce
                limit[c] = np.float32(np.inf)
            alpha[c] = rz[c] / pq[c] if rz[c] > limit[c] else zero
            beta[c] = rz[c]  # the old rz, divided out below
        _update(x, r, p, q, inverse_diagonal, alpha, rz)
        for c in range(s):
            beta[c] = rz[c] / beta[c] if alpha[c] != zero else zero
        _direction(r, p, inverse_diagonal, beta)
        done += 1
    return done


@njit(inline="always", **_STRICT)
def _guess(u, up, free, restart, holding, x):  # pragma: no cover - compiled
    """``x``: the first guess of ``u_{n+1}``, ``u_n`` at a restart and ``2 u_n - u_{n-1}`` after; 1 on held rows."""
    n, s = u.shape
    one, two = vsplat(np.float32(1.0)), vsplat(np.float32(2.0))
    for o in range(0, n * s, LANES):
        xi = vload(u, o) if restart else two * vload(u, o) - vload(up, o)
        if holding:
            held = one - vload(free, o)
            xi = vfma(xi, vload(free, o), held)
        vstore(x, o, xi)


@njit(nogil=True, cache=True, **_STRICT)
def _run_block(
    matrices, a, u0, free, counts, params, cell, solver, perm, col0, frames, act, iterations
):  # pragma: no cover - compiled
    """Every step of one block of columns, ``col0`` its first column in the run (see :func:`run_imex_cg`).

    ``matrices = (indptr, indices, offdiagonal, step diagonal, start diagonal, mass)``;
    ``solver = (tol^2, max iterations)``; ``iterations[0]`` receives the
    iterations of all solves, ``iterations[1]`` the solves that hit the limit.
    """
    ptr, idx, off, step_diagonal, start_diagonal, mass = matrices
    stim_steps, n_steps, out_every = counts
    dt, thr, v_rest = params
    tol2, max_iterations = solver
    s = u0.shape[1]
    u = u0.copy()
    x, v, up, vp = np.zeros_like(u), np.full_like(u, v_rest), np.zeros_like(u), np.zeros_like(u)
    fp, gp, rhs, change = np.zeros_like(u), np.zeros_like(u), np.zeros_like(u), np.zeros_like(u)
    columns = np.zeros((6, s), np.float32)
    work = (np.zeros_like(u), np.zeros_like(u), np.zeros_like(u)) + (
        columns[0],
        columns[1],
        columns[2],
        columns[3],
        columns[4],
        columns[5],
    )
    step_inverse = (np.float32(1.0) / step_diagonal).astype(np.float32)
    start_inverse = (np.float32(1.0) / start_diagonal).astype(np.float32)
    frame = 0
    for step in range(n_steps):
        restart = step == 0 or step == stim_steps
        holding = step < stim_steps
        _guess(u, up, free, restart, holding, x)
        _explicit(u, v, up, vp, fp, gp, rhs, mass, a, restart, dt, cell)
        diagonal, inverse = (start_diagonal, start_inverse) if restart else (step_diagonal, step_inverse)
        _change(rhs, u, mass, np.float32(1.0) if restart else np.float32(1.5), change)
        done = _cg(ptr, idx, off, diagonal, inverse, x, rhs, change, free, holding, tol2, max_iterations, work)
        iterations[0] += done
        if done >= max_iterations:
            iterations[1] += 1
        _record(u, x, act, np.float32(step) * dt, dt, thr)
        u, x = x, u
        if (step + 1) % out_every == 0:
            _output(u, perm, col0, frames, frame)
            frame += 1


def run_imex_cg(
    matrices: Implicit,
    a: NDArray[np.float32],
    stim: NDArray[np.bool_],
    counts: tuple[int, int, int],
    params: tuple[np.float32, ...],
    cell: tuple,
    perm: NDArray[np.int64],
    frames: NDArray[np.float32],
    act: NDArray[np.float32],
    width: int,
    threads: int = 1,
    initial: NDArray[np.float32] | None = None,
    tol: float = TOL,
) -> tuple[int, int, int]:
    """Integrate an IMEX-Euler step, then SBDF2 steps, of every column of the (N, S) stimulus mask ``stim``.

    Arguments as :func:`simgen.solver.imex_kernel.run_imex`'s, with arrays in
    ``matrices``' node order (``perm[i]``: the mesh node of row ``i``, where
    ``frames`` puts it); ``tol``: the CG stopping tolerance (:data:`TOL`).
    Returns the solves, their CG iterations and the solves that stopped at
    :data:`MAX_ITERATIONS` instead of the tolerance, summed over the blocks
    (padding columns included).
    """
    s = stim.shape[1]
    padded, u0, block_act = padded_blocks(stim, act, width, initial)
    free = (~padded).astype(np.float32)
    fields = (matrices.indptr, matrices.indices, matrices.offdiagonal)
    fields += (matrices.step_diagonal, matrices.start_diagonal, matrices.mass)
    solver = (np.float32(tol**2), np.int64(MAX_ITERATIONS))
    counts = tuple(int(c) for c in counts)
    totals = np.zeros((padded.shape[1] // width, 2), np.int64)

    def run_block(start: int) -> None:
        columns = slice(start, start + width)
        block = np.ascontiguousarray(block_act[:, columns])
        u_block, free_block = np.ascontiguousarray(u0[:, columns]), np.ascontiguousarray(free[:, columns])
        tally = totals[start // width]
        _run_block(fields, a, u_block, free_block, counts, params, cell, solver, perm, start, frames, block, tally)
        block_act[:, columns] = block

    blocks = each_block(padded.shape[1], width, threads, run_block)
    act[:] = block_act[:, :s]
    return blocks * counts[1], int(totals[:, 0].sum()), int(totals[:, 1].sum())
