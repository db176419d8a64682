"""Fused explicit-Euler kernel: sparse diffusion product + Aliev-Panfilov reaction.

One pass per time step reads each node's CSR row once, forms the diffusion
term for a block of simulations (one column per stimulation site) with
explicit 8-lane vectors (:mod:`simgen.solver.simd`: 32 columns per sweep of
the row, accumulators in registers), updates ``u`` and ``v`` in place and
records activation times. Threads split the batch of sites into independent
blocks that never synchronise, so a Dask worker can run the kernel
single-threaded without stalls.
All arithmetic is float32; constants are cast so nothing is promoted. Multiply-adds
fuse into FMAs (``fastmath={"contract"}`` only: no reassociation), the same
way in every column, so results stay independent of threads and block size."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from simgen.solver.simd import LANES, vfma, vload, vmul, vsplat, vstore

__all__ = ["run_blocks"]


@njit(inline="always", error_model="numpy", boundscheck=False, fastmath={"contract"})
def _laplacian_row(indptr, indices, data, diag, u, i, lap):  # pragma: no cover - compiled
    """``lap[:] = diag[i] u[i] + sum_p data[p] u[indices[p]]`` over row ``i`` of the CSR part.

    Columns go 32 at a time (four vector accumulators kept in registers across
    the row), then 8 at a time, then one at a time; every column sums in the
    same order with one fused multiply-add per neighbour, so a column's result
    does not depend on which of the three paths it took (or on the block width).
    """
    b = u.shape[1]
    b32 = b - b % (4 * LANES)
    b8 = b - b % LANES
    d = vsplat(diag[i])
    start, end = indptr[i], indptr[i + 1]
    row = i * b
    for c in range(0, b32, 4 * LANES):
        a0, a1 = vmul(d, vload(u, row + c)), vmul(d, vload(u, row + c + 8))
        a2, a3 = vmul(d, vload(u, row + c + 16)), vmul(d, vload(u, row + c + 24))
        for p in range(start, end):
            w, q = vsplat(data[p]), indices[p] * b + c
            a0, a1 = vfma(w, vload(u, q), a0), vfma(w, vload(u, q + 8), a1)
            a2, a3 = vfma(w, vload(u, q + 16), a2), vfma(w, vload(u, q + 24), a3)
        vstore(lap, c, a0)
        vstore(lap, c + 8, a1)
        vstore(lap, c + 16, a2)
        vstore(lap, c + 24, a3)
    for c in range(b32, b8, LANES):
        a0 = vmul(d, vload(u, row + c))
        for p in range(start, end):
            a0 = vfma(vsplat(data[p]), vload(u, indices[p] * b + c), a0)
        vstore(lap, c, a0)
    for c in range(b8, b):
        acc = diag[i] * u[i, c]
        for p in range(start, end):
            acc += data[p] * u[indices[p], c]
        lap[c] = acc


@njit(cache=True, error_model="numpy", boundscheck=False, fastmath={"contract"})
def _run_block(
    indptr, indices, data, diag, a, u_init, stim, stim_steps, n_steps, out_every, dt, k, eps0, mu1, mu2, thr, frames, act
):  # pragma: no cover - compiled
    n, b = u_init.shape
    u = u_init.copy()
    un = np.empty_like(u)
    v = np.zeros_like(u)
    lap = np.empty(b, dtype=np.float32)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    frame = 0
    for step in range(n_steps):
        t0 = np.float32(step) * dt
        stimulating = step < stim_steps
        for i in range(n):
            # Row views; indexing [i, c] directly defeats LLVM's vectoriser here.
            u_i, v_i, un_i, act_i, stim_i = u[i], v[i], un[i], act[i], stim[i]
            _laplacian_row(indptr, indices, data, diag, u, i, lap)
            ai = a[i]
            crossed = False
            for c in range(b):
                ui = u_i[c]
                vi = v_i[c]
                du = lap[c] + k * ui * (one - ui) * (ui - ai) - ui * vi
                # the constant-eps variant is passed as eps0 = eps, mu1 = 0
                eps = eps0 + mu1 * vi / (ui + mu2)
                dv = eps * (-vi - k * ui * (ui - ai - one))
                unew = ui + dt * du
                un_i[c] = unew
                v_i[c] = vi + dt * dv
                crossed |= (ui < thr) & (unew >= thr)
            if stimulating:  # stimulated nodes are held at u = 1 (their activation time is 0)
                for c in range(b):
                    if stim_i[c]:
                        un_i[c] = one
            if crossed:  # rare: record interpolated first-crossing times outside the vector loop
                for c in range(b):
                    ui = u_i[c]
                    unew = un_i[c]
                    if ui < thr <= unew and act_i[c] < zero:
                        act_i[c] = t0 + dt * (thr - ui) / (unew - ui)
        u, un = un, u
        if (step + 1) % out_every == 0:
            frames[frame] = u
            frame += 1


@njit(parallel=True, cache=True, error_model="numpy")
def run_blocks(
    indptr, indices, data, diag, a, u_init, stim, stim_steps, n_steps, out_every, dt, k, eps0, mu1, mu2, thr, frames, act
):  # pragma: no cover - compiled
    """Integrate ``n_steps`` steps for every block of sites.

    Parameters
    ----------
    indptr, indices, data, diag : off-diagonal CSR part and diagonal of the
        diffusion operator ``-M^{-1}K`` (float32 values).
    a : (N,) float32 excitability.
    u_init : (n_blocks, N, B) float32 initial ``u`` (``v`` starts at 0).
    stim, stim_steps : (n_blocks, N, B) bool mask of stimulated nodes, held at
        ``u = 1`` for the first ``stim_steps`` steps.
    eps0, mu1, mu2 : recovery-rate constants; the constant-eps variant passes
        ``eps0 = eps``, ``mu1 = 0``.
    frames : (n_blocks, F, N, B) float32 output, written every ``out_every`` steps.
    act : (n_blocks, N, B) float32 activation times, initialised to -1 (never).
    """
    for blk in prange(u_init.shape[0]):
        _run_block(
            indptr, indices, data, diag, a, u_init[blk], stim[blk], stim_steps, n_steps, out_every, dt, k, eps0, mu1, mu2,
            thr, frames[blk], act[blk],
        )
