"""Second-order Runge-Kutta-Chebyshev (RKC2) integrator: stage coefficients and a numba kernel.

RKC2 (Sommeijer, Shampine & Verwer 1998, "RKC: an explicit solver for
parabolic PDEs", J. Comput. Appl. Math. 88: 315-326; Verwer, Sommeijer &
Hundsdorfer 2004, "RKC time-stepping for advection-diffusion-reaction
problems", J. Comput. Phys. 201: 61-79) advances ``y' = F(y)`` by one step
``dt`` through ``s >= 2`` stages built on the Chebyshev polynomials ``T_j`` at
``w0 = 1 + eps / s^2`` (damping ``eps = 2/13``)::

    Y_0 = y_n,   Y_1 = Y_0 + mu~_1 dt F(Y_0),
    Y_j = (1 - mu_j - nu_j) Y_0 + mu_j Y_{j-1} + nu_j Y_{j-2} + mu~_j dt F(Y_{j-1}) + gamma~_j dt F(Y_0),
    y_{n+1} = Y_s,

with ``w1 = T_s'(w0) / T_s''(w0)``, ``b_j = T_j''(w0) / T_j'(w0)^2`` (``b_0 = b_1 = b_2``),
``a_j = 1 - b_j T_j(w0)``, ``mu~_1 = b_1 w1`` and for ``j >= 2``
``mu_j = 2 b_j w0 / b_{j-1}``, ``nu_j = -b_j / b_{j-2}``, ``mu~_j = 2 b_j w1 / b_{j-1}``,
``gamma~_j = -a_{j-1} mu~_j``. The step is second order for every ``s``; on
``y' = lambda y`` it multiplies ``y`` by ``R_s(z) = a_s + b_s T_s(w0 + w1 z)``,
``z = dt lambda``, which stays within [-1, 1] for ``z`` in ``[-beta(s), 0]``,
``beta(s) = (1 + w0) / w1`` (about ``0.653 s^2``). So ``s`` products with the
diffusion operator cover a stiffness that forward Euler needs ``~0.33 s^2``
steps for, and meshes whose explicit limit is far below the accuracy step
(thin-walled real meshes) integrate at the accuracy step (docs/solver-backends.md).
The price: stiff modes are damped only by ``|R_s| <= 1 - eps / 3`` (~0.95) per
step, so a non-smooth start (the stimulus switched on at ``t = 0``) relaxes over
several steps at the nodes coupled most stiffly to the stimulated patch.

:func:`run_blocks_rkc` integrates blocks of sites with the inputs and outputs of
:func:`simgen.solver.kernels.run_blocks`. ``u`` and ``v`` both go through the
stages; the stimulated nodes are held at ``u = 1`` in every stage of the
stimulus steps; activation times interpolate ``u`` linearly between ``y_n``
and ``y_{n+1}``. Float32 throughout, :data:`~simgen.solver.simd.LANES`
columns at a time as in the Euler kernel, the last ``B % LANES`` of a block
one by one. Every product that is added is an explicit fused multiply-add
(the diffusion term one per neighbour, in CSR order) and no other product
meets an addition, so no rounding is left to the compiler: a column's result
is the same on either path and with either compiled copy of the kernel
(in-process or from numba's cache), whatever the threads or block width.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from simgen.solver.cells.ops import cell_rates, fma, splat
from simgen.solver.simd import LANES, vload, vsplat, vstore

__all__ = ["DAMPING", "chebyshev", "stability_bound", "coefficients", "run_blocks_rkc"]

#: Damping ``eps`` of the stability polynomial (the RKC code's value): it keeps ``|R_s|`` below
#: ``1 - eps / 3`` inside the stability interval, which costs ~2% of the interval's length.
DAMPING = 2.0 / 13.0

_STRICT = dict(error_model="numpy", boundscheck=False)  # no fastmath: no contraction the compiler may choose


def chebyshev(s: int, x: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``T_j(x)``, ``T_j'(x)``, ``T_j''(x)`` for ``j = 0..s`` from the three-term recurrences."""
    t, d1, d2 = np.zeros(s + 1), np.zeros(s + 1), np.zeros(s + 1)
    t[0], t[1], d1[1] = 1.0, x, 1.0
    for j in range(2, s + 1):
        t[j] = 2 * x * t[j - 1] - t[j - 2]
        d1[j] = 2 * t[j - 1] + 2 * x * d1[j - 1] - d1[j - 2]
        d2[j] = 4 * d1[j - 1] + 2 * x * d2[j - 1] - d2[j - 2]
    return t, d1, d2


def stability_bound(s: int) -> float:
    """``beta(s) = (1 + w0) / w1``: RKC2 with ``s`` stages is stable for ``dt lambda`` in ``[-beta(s), 0]``."""
    if s < 2:
        raise ValueError(f"RKC2 needs at least 2 stages, got {s}")
    w0 = 1.0 + DAMPING / s**2
    _, d1, d2 = chebyshev(s, w0)
    return (1.0 + w0) * d2[s] / d1[s]


def coefficients(s: int) -> NDArray[np.float64]:
    """(s, 5) rows ``(1 - mu_j - nu_j, mu_j, nu_j, mu~_j, gamma~_j)`` of stages ``j = 1..s``.

    Stage 1 is ``(1, 0, 0, mu~_1, 0)``, so every stage is one formula
    (``Y_{-1}`` does not matter: its weight is 0).
    """
    if s < 2:
        raise ValueError(f"RKC2 needs at least 2 stages, got {s}")
    w0 = 1.0 + DAMPING / s**2
    t, d1, d2 = chebyshev(s, w0)
    w1 = d1[s] / d2[s]
    b = np.empty(s + 1)
    b[2:] = d2[2:] / d1[2:] ** 2
    b[:2] = b[2]
    a = 1.0 - b * t
    rows = np.zeros((s, 5))
    rows[0] = 1.0, 0.0, 0.0, b[1] * w1, 0.0
    for j in range(2, s + 1):
        mu, nu, mu_t = 2 * b[j] * w0 / b[j - 1], -b[j] / b[j - 2], 2 * b[j] * w1 / b[j - 1]
        rows[j - 1] = 1.0 - mu - nu, mu, nu, mu_t, -a[j - 1] * mu_t
    return rows


@njit(inline="always", **_STRICT)
def _combine(y0, y1, y2, f1, f0, weights):  # pragma: no cover - compiled
    """``Y_j`` from ``Y_0, Y_{j-1}, Y_{j-2}, F(Y_{j-1}), F(Y_0)`` and the stage's ``weights`` (dt folded in)."""
    c0, mu, nu, mu_dt, gamma_dt = weights
    return fma(gamma_dt, f0, fma(mu_dt, f1, fma(nu, y2, fma(mu, y1, c0 * y0))))


@njit(inline="always", **_STRICT)
def _stage_row(indptr, indices, data, diag, y, yn, f0, i, first, params, weights):  # pragma: no cover
    """Row ``i`` of stage ``j`` in every column: ``yn[i] = (u, v)`` of ``Y_j`` from ``y = (Y_0, Y_{j-1}, Y_{j-2})``.

    ``y`` and ``yn`` hold (N, B) ``u`` and ``v`` arrays, ``f0`` those of
    ``F(Y_0)``, written in stage 1 (``first``); ``params = (a[i], cell)``,
    ``cell`` the cell model's constants. :data:`~simgen.solver.simd.LANES`
    columns at a time, the last ``B % LANES`` one by one, with the same
    operations: the diffusion term in CSR order, one fused multiply-add per neighbour.
    """
    (u0, v0), (u1, v1), (u2, v2) = y
    un, vn = yn
    fu0, fv0 = f0
    b = u1.shape[1]
    b_vec = b - b % LANES
    start, end = indptr[i], indptr[i + 1]
    a, cell = params
    va, vcell = vsplat(a), splat(cell)
    c0, mu, nu, mu_dt, gamma_dt = weights
    vweights = (vsplat(c0), vsplat(mu), vsplat(nu), vsplat(mu_dt), vsplat(gamma_dt))
    d = vsplat(diag[i])
    for c in range(0, b_vec, LANES):
        o = i * b + c
        lap = d * vload(u1, o)
        for p in range(start, end):
            lap = fma(vsplat(data[p]), vload(u1, indices[p] * b + c), lap)
        du, dv = cell_rates(vload(u1, o), vload(v1, o), lap, va, vcell)
        if first:
            vstore(fu0, o, du)
            vstore(fv0, o, dv)
        vstore(un, o, _combine(vload(u0, o), vload(u1, o), vload(u2, o), du, vload(fu0, o), vweights))
        vstore(vn, o, _combine(vload(v0, o), vload(v1, o), vload(v2, o), dv, vload(fv0, o), vweights))
    for c in range(b_vec, b):
        lap = diag[i] * u1[i, c]
        for p in range(start, end):
            lap = fma(data[p], u1[indices[p], c], lap)
        du, dv = cell_rates(u1[i, c], v1[i, c], lap, a, cell)
        if first:
            fu0[i, c], fv0[i, c] = du, dv
        un[i, c] = _combine(u0[i, c], u1[i, c], u2[i, c], du, fu0[i, c], weights)
        vn[i, c] = _combine(v0[i, c], v1[i, c], v2[i, c], dv, fv0[i, c], weights)


@njit(inline="always")
def _slot(j):  # pragma: no cover - compiled
    """Buffer of stage ``j``: 0 holds ``Y_0``, stages 1, 2, 3, 4, ... rotate through 1, 2, 3, 1, ..."""
    return 0 if j == 0 else 1 + (j - 1) % 3


@njit(cache=True, **_STRICT)
def _run_block(
    indptr, indices, data, diag, a, u_init, stim, counts, params, cell, perm, frames, act, stages
):  # pragma: no cover
    stim_steps, n_steps, out_every = counts
    dt, thr, v_rest = params
    n, b = u_init.shape
    s = stages.shape[0]
    yu = np.empty((4, n, b), np.float32)  # Y_0 and three rotating stages, u and v
    yv = np.full((4, n, b), v_rest, np.float32)
    yu[0] = u_init
    f0 = (np.empty((n, b), np.float32), np.empty((n, b), np.float32))  # F(Y_0), u and v
    one, zero = np.float32(1.0), np.float32(0.0)
    frame = 0
    for step in range(n_steps):
        t0 = np.float32(step) * dt
        for j in range(1, s + 1):
            c0, mu, nu, mu_t, gamma_t = stages[j - 1]
            weights = (c0, mu, nu, mu_t * dt, gamma_t * dt)
            p1, p2, cur = _slot(j - 1), _slot(max(j - 2, 0)), _slot(j)
            y = ((yu[0], yv[0]), (yu[p1], yv[p1]), (yu[p2], yv[p2]))
            yn = (yu[cur], yv[cur])
            for i in range(n):
                _stage_row(indptr, indices, data, diag, y, yn, f0, i, j == 1, (a[i], cell), weights)
                if step < stim_steps:  # stimulated nodes are held at u = 1 in every stage
                    for c in range(b):
                        if stim[i, c]:
                            yu[cur, i, c] = one
        last = _slot(s)
        for i in range(n):  # interpolated first crossings within the step, then Y_s becomes Y_0
            for c in range(b):
                ui, unew = yu[0, i, c], yu[last, i, c]
                if ui < thr <= unew and act[i, c] < zero:
                    act[i, c] = t0 + dt * (thr - ui) / (unew - ui)
        yu[0] = yu[last]
        yv[0] = yv[last]
        if (step + 1) % out_every == 0:
            for c in range(b):
                for i in range(n):
                    frames[c, frame, perm[i]] = yu[0, i, c]
            frame += 1


@njit(parallel=True, nogil=True, cache=True, error_model="numpy")
def run_blocks_rkc(
    indptr, indices, data, diag, a, u_init, stim, counts, params, cell, perm, frames, act, stages
):  # pragma: no cover - compiled
    """Integrate ``n_steps`` RKC2 steps for every block of sites.

    The arguments before ``stages`` are those of
    :func:`simgen.solver.kernels.run_blocks`; ``stages`` is the (s, 5) float32
    :func:`coefficients` table.
    """
    for blk in prange(u_init.shape[0]):
        u0, stim0, frames0, act0 = u_init[blk], stim[blk], frames[blk], act[blk]
        _run_block(indptr, indices, data, diag, a, u0, stim0, counts, params, cell, perm, frames0, act0, stages)
