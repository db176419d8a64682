"""Fused explicit-Euler kernel: sparse diffusion product + the cell model's reaction.

One pass per time step reads each node's CSR row once, forms the diffusion
term for a block of simulations (one column per stimulation site) with
explicit vectors (:mod:`simgen.solver.simd`: ``4 * LANES`` columns per sweep
of the row, 32 or 64, accumulators in registers), updates ``u`` and ``v`` in place and
records activation times. Threads split the batch of sites into independent
blocks that never synchronise, so a Dask worker can run the kernel
single-threaded without stalls.
All arithmetic is float32; constants are cast so nothing is promoted. Multiply-adds
fuse into FMAs (``fastmath={"contract"}`` only: no reassociation), the same
way in every column, so results stay independent of threads and block size."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from simgen.solver.cells.ops import cell_rates, splat
from simgen.solver.simd import LANES, vany, vfma, vload, vsplat, vstore

__all__ = ["run_blocks"]


_FAST = dict(error_model="numpy", boundscheck=False, fastmath={"contract"})


@njit(inline="always", **_FAST)
def _reaction(u, v, lap, a, cell, dt):  # pragma: no cover - compiled
    """Explicit-Euler update ``(u, v) -> (u', v')`` from the diffusion term ``lap`` and the cell model's
    rates (:func:`~simgen.solver.cells.ops.cell_rates`; ``cell`` its constants). All values float32 or all
    :data:`~simgen.solver.simd.float32_vector` (same operations, same rounding)."""
    du, dv = cell_rates(u, v, lap, a, cell)
    return u + dt * du, v + dt * dv


@njit(inline="always", **_FAST)
def _update_lanes(u, v, un, offset, lap, thr, params):  # pragma: no cover - compiled
    """Update the columns of the vector at flat ``offset`` from their diffusion term; True if one crossed ``thr``.
    ``params = (a, cell, dt)`` as :func:`_reaction` takes them."""
    ui, vi = vload(u, offset), vload(v, offset)
    a, cell, dt = params
    unew, vnew = _reaction(ui, vi, lap, a, cell, dt)
    vstore(un, offset, unew)
    vstore(v, offset, vnew)
    return vany((ui < thr) & (unew >= thr))


@njit(inline="always", **_FAST)
def _sweep(indices, data, u, v, un, row, b, start, end, offsets, n_vec, d, thr, params):  # pragma: no cover
    """The first ``n_vec`` (1-4) of four column vectors at ``offsets`` in one row, in one pass over its neighbours.

    The four accumulators stay in registers across the row. With fewer than
    four vectors left the caller repeats the last offset: the spare
    accumulators redo that vector (loads that hit L1, multiply-adds that run
    in parallel) and are not stored, so one pass still serves the whole rest
    of the row instead of one latency-bound pass per vector. Returns True if
    any column crossed ``thr``.
    """
    o0, o1, o2, o3 = offsets
    a0, a1 = d * vload(u, row + o0), d * vload(u, row + o1)
    a2, a3 = d * vload(u, row + o2), d * vload(u, row + o3)
    for p in range(start, end):
        w, q = vsplat(data[p]), indices[p] * b
        a0, a1 = vfma(w, vload(u, q + o0), a0), vfma(w, vload(u, q + o1), a1)
        a2, a3 = vfma(w, vload(u, q + o2), a2), vfma(w, vload(u, q + o3), a3)
    crossed = _update_lanes(u, v, un, row + o0, a0, thr, params)
    if n_vec > 1:
        crossed |= _update_lanes(u, v, un, row + o1, a1, thr, params)
    if n_vec > 2:
        crossed |= _update_lanes(u, v, un, row + o2, a2, thr, params)
    if n_vec > 3:
        crossed |= _update_lanes(u, v, un, row + o3, a3, thr, params)
    return crossed


@njit(inline="always", **_FAST)
def _step_row(indptr, indices, data, diag, u, v, un, i, thr, params):  # pragma: no cover - compiled
    """One time step of node ``i`` in every column: ``un[i]`` and ``v[i]`` from ``u`` and ``v``
    (``params = (a[i], cell, dt)``).

    The diffusion term ``diag[i] u[i] + sum_p data[p] u[indices[p]]`` (CSR row
    ``i``) is summed ``4 * LANES`` columns per pass of the row (:func:`_sweep`),
    the last one to three vectors in one more pass, the last ``b % LANES`` one
    at a time, and fed to the reaction in registers. Every column sums in the same
    order with one fused multiply-add per neighbour, so its result does not
    depend on the path it took (or on the block width). Returns True if any
    column crossed ``thr``.
    """
    b = u.shape[1]
    b_full = b - b % (4 * LANES)  # columns in passes of four vectors
    b_vec = b - b % LANES  # columns in vectors
    start, end = indptr[i], indptr[i + 1]
    row = i * b
    d, vthr = vsplat(diag[i]), vsplat(thr)
    a, cell, dt = params
    vparams = (vsplat(a), splat(cell), vsplat(dt))
    crossed = False
    for c in range(0, b_full, 4 * LANES):  # offsets c + constants: one address per neighbour (4 runtime ones cost 2x)
        offsets = (c, c + LANES, c + 2 * LANES, c + 3 * LANES)
        crossed |= _sweep(indices, data, u, v, un, row, b, start, end, offsets, 4, d, vthr, vparams)
    if b_vec > b_full:
        top = b_vec - LANES
        offsets = (b_full, min(b_full + LANES, top), min(b_full + 2 * LANES, top), top)
        n_vec = (b_vec - b_full) // LANES
        crossed |= _sweep(indices, data, u, v, un, row, b, start, end, offsets, n_vec, d, vthr, vparams)
    for c in range(b_vec, b):
        ui = u[i, c]
        lap = diag[i] * ui
        for p in range(start, end):
            lap += data[p] * u[indices[p], c]
        unew, v[i, c] = _reaction(ui, v[i, c], lap, a, cell, dt)
        un[i, c] = unew
        crossed |= (ui < thr) & (unew >= thr)
    return crossed


@njit(cache=True, **_FAST)
def _run_block(
    indptr, indices, data, diag, a, u_init, stim, counts, params, cell, perm, frames, act
):  # pragma: no cover
    stim_steps, n_steps, out_every = counts
    dt, thr, v_rest = params
    n, b = u_init.shape
    u = u_init.copy()
    un = np.empty_like(u)
    v = np.full_like(u, v_rest)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    frame = 0
    for step in range(n_steps):
        t0 = np.float32(step) * dt
        stimulating = step < stim_steps
        for i in range(n):
            crossed = _step_row(indptr, indices, data, diag, u, v, un, i, thr, (a[i], cell, dt))
            if stimulating:  # stimulated nodes are held at u = 1 (their activation time is 0)
                for c in range(b):
                    if stim[i, c]:
                        un[i, c] = one
            if crossed:  # rare: record interpolated first-crossing times outside the vector loops
                for c in range(b):
                    ui, unew = u[i, c], un[i, c]
                    if ui < thr <= unew and act[i, c] < zero:
                        act[i, c] = t0 + dt * (thr - ui) / (unew - ui)
        u, un = un, u
        if (step + 1) % out_every == 0:  # straight into the result's (site, frame, node) layout, mesh order
            for c0 in range(0, b, 16):  # 16 columns (a cache line of a row) at a time: 16 output rows in flight
                for i in range(n):
                    j = perm[i]
                    for c in range(c0, min(c0 + 16, b)):
                        frames[c, frame, j] = u[i, c]
            frame += 1


# nogil: a build worker's writer thread (simgen.store.worker.BackgroundWriter) runs while a chunk simulates
@njit(parallel=True, nogil=True, cache=True, error_model="numpy")
def run_blocks(
    indptr, indices, data, diag, a, u_init, stim, counts, params, cell, perm, frames, act
):  # pragma: no cover
    """Integrate ``n_steps`` steps for every block of sites.

    Parameters
    ----------
    indptr, indices, data, diag : off-diagonal CSR part and diagonal of the
        diffusion operator ``-M^{-1}K`` (float32 values).
    a : (N,) float32 excitability.
    u_init : (n_blocks, N, B) float32 initial ``u`` (``v`` starts at 0).
    stim : (n_blocks, N, B) bool mask of stimulated nodes, held at ``u = 1``
        for the first ``stim_steps`` steps.
    counts : ``(stim_steps, n_steps, out_every)``: steps of stimulus, steps in all, steps per output frame.
    params : ``(dt, thr, v_rest)`` float32: the time step, the activation threshold and ``v`` at rest.
    cell : the cell model's constants (:meth:`~simgen.solver.cells.aliev_panfilov.APParams.constants`),
        whose class chooses its rates when the kernel compiles.
    perm : (N,) mesh node of each kernel row (the rows are renumbered for locality).
    frames : (n_blocks, B, F, N) float32 output, written every ``out_every`` steps, nodes in mesh order.
    act : (n_blocks, N, B) float32 activation times, initialised to -1 (never).
    """
    for blk in prange(u_init.shape[0]):
        u0, stim0, frames0, act0 = u_init[blk], stim[blk], frames[blk], act[blk]
        _run_block(indptr, indices, data, diag, a, u0, stim0, counts, params, cell, perm, frames0, act0)
