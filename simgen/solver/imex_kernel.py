"""Implicit-explicit (IMEX) integrator: SBDF2, the diffusion implicit and the reaction explicit.

The second-order semi-implicit backward differentiation formula (SBDF2;
Ascher, Ruuth & Wetton 1995, "Implicit-explicit methods for time-dependent
partial differential equations", SIAM J. Numer. Anal. 32: 797-823) advances
``M du/dt = -K u + M f(u, v)``, ``dv/dt = g(u, v)`` (lumped mass ``M``,
stiffness ``K``, Aliev-Panfilov rates ``f``, ``g``) by::

    (3/2 M + dt K) u_{n+1} = M (2 u_n - u_{n-1} / 2 + dt (2 f_n - f_{n-1})),
    v_{n+1} = (4 v_n - v_{n-1} + 2 dt (2 g_n - g_{n-1})) / 3,

with ``f_n = f(u_n, v_n)``. The method restarts with one IMEX-Euler step,
``(M + dt K) u_{n+1} = M (u_n + dt f_n)``, ``v_{n+1} = v_n + dt g_n``, at
``t = 0`` and where the stimulus switches off (the history does not reach
across that jump). BDF2 damps every diffusion mode, so no element, however
thin, limits ``dt``: the step is chosen for the accuracy of the reaction
(:data:`simgen.solver.timestep.DT_IMEX`).

Both matrices are symmetric positive definite and the same at every step:
:func:`factorise` factors them once per subject (one minimum degree ordering
of the mesh graph, SuperLU without pivoting, so ``B = P^T L U P`` with
``U = D L^T``), and each step solves every site of the batch as one column of
the right-hand side, float32, with one fused multiply-add per factor entry in
a fixed order: a column's result does not depend on the other columns, the
block width or the threads.

The stimulus holds ``u = 1`` on each site's patch for ``stim_steps`` steps as
a Dirichlet condition of the implicit solve (not as a reset after it, which
would leak an error of order ``dt`` into the wave's launch): with the patch
``C`` of a column, the capacitance matrix ``G = (B^{-1})_{CC}``, computed once
per run, gives the multipliers ``lambda = G^{-1} (1 - u_C)`` and a second
solve adds ``B^{-1} E_C lambda`` (:class:`Patches`).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit
from numpy.typing import NDArray

from shared.errors import InputError
from simgen.solver.cells.ops import cell_rates, fma, splat
from simgen.solver.simd import LANES, vany, vfma, vload, vsplat, vstore

__all__ = ["Factor", "Factors", "factorise", "Patches", "patches", "run_imex"]

_STRICT = dict(error_model="numpy", boundscheck=False)  # IEEE operations as written: the same on every path


@dataclass(frozen=True)
class Factor:
    """One matrix ``B`` (factor order) factored as ``L U``, as float32 CSR triangles.

    ``lower``: strict lower triangle of ``L`` (unit diagonal), ``upper``: strict
    upper triangle of ``U``, each ``(indptr, indices, data)``;
    ``inverse_diagonal``: ``1 / diag(U)``.
    """

    lower: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]
    upper: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]
    inverse_diagonal: NDArray[np.float32]

    @property
    def triangles(self) -> tuple:
        """The kernel's operands: the two triangles' arrays and the inverse diagonal."""
        return (*self.lower, *self.upper, self.inverse_diagonal)

    @property
    def nnz(self) -> int:
        """Stored entries, diagonal included: the multiply-adds of one solve per column."""
        return len(self.lower[2]) + len(self.upper[2]) + len(self.inverse_diagonal)


@dataclass(frozen=True)
class Factors:
    """The two implicit matrices of SBDF2 with step ``dt``, in one fill-reducing node order.

    ``perm[i]``: the mesh node of factor row ``i``; ``mass``: the lumped mass in
    that order (float32); ``step``: ``3/2 M + dt K``; ``start``: ``M + dt K``
    (the restarting IMEX-Euler steps).
    """

    perm: NDArray[np.int64]
    mass: NDArray[np.float32]
    step: Factor
    start: Factor

    @property
    def nnz(self) -> int:
        """Entries of the factor that steps but the restarting ones solve with."""
        return self.step.nnz


def factorise(stiffness: sp.spmatrix, mass: NDArray[np.float64], dt: float) -> Factors:
    """:class:`Factors` of ``K`` (stiffness matrix) and ``mass`` (lumped) for SBDF2 steps of ``dt``.

    The order is SuperLU's minimum degree ordering of the pattern of ``K``,
    found while factoring ``M + dt K``; ``3/2 M + dt K`` is factored in it.
    """
    mass = np.asarray(mass, float)
    K = sp.csc_matrix(stiffness)
    start = _splu(sp.diags(mass) + dt * K, "MMD_AT_PLUS_A")
    perm = np.argsort(start.perm_c).astype(np.int64)  # factor row -> mesh node
    m = mass[perm]
    step = _splu(sp.diags(1.5 * m) + dt * K[perm][:, perm], "NATURAL")
    if not np.array_equal(step.perm_c, np.arange(len(m))):  # pragma: no cover - NATURAL keeps the order
        raise InputError("SuperLU reordered the implicit diffusion matrix")
    return Factors(perm, m.astype(np.float32), _factor(step), _factor(start))


def _splu(B: sp.spmatrix, ordering: str) -> spla.SuperLU:
    """SuperLU's factor of the symmetric positive definite ``B`` with a symmetric ``ordering``, no pivoting."""
    lu = spla.splu(B.tocsc(), permc_spec=ordering, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    if not np.array_equal(lu.perm_r, lu.perm_c):
        raise InputError("the implicit diffusion matrix needed pivoting: is the stiffness matrix symmetric?")
    return lu


def _factor(lu: spla.SuperLU) -> Factor:
    """:class:`Factor` of SuperLU's ``L U`` (in its own node order)."""
    U = lu.U.tocsr()
    diag = U.diagonal()
    if np.any(diag <= 0):  # pragma: no cover - B is positive definite
        raise InputError("the implicit diffusion matrix is not positive definite")
    lower, upper = sp.tril(lu.L.tocsr(), k=-1, format="csr"), sp.triu(U, k=1, format="csr")
    return Factor(_csr32(lower), _csr32(upper), (1.0 / diag).astype(np.float32))


def _csr32(A: sp.csr_matrix) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    A.sort_indices()
    return A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data.astype(np.float32)


@dataclass(frozen=True)
class Patches:
    """Each column's stimulated rows (factor order) and the inverse of its capacitance matrix.

    Column ``c`` holds rows ``rows[offsets[c]:offsets[c + 1]]`` and the
    row-major inverse ``(B^{-1})_{CC}^{-1}`` in ``inverse[squares[c]:squares[c + 1]]``.
    """

    offsets: NDArray[np.int64]
    rows: NDArray[np.int64]
    squares: NDArray[np.int64]
    inverse: NDArray[np.float32]

    @property
    def tables(self) -> tuple:
        """The kernel's operands."""
        return self.offsets, self.rows, self.squares, self.inverse


def patches(factor: Factor, stim: NDArray[np.bool_]) -> Patches:
    """:class:`Patches` of the (N, S) stimulus mask ``stim`` (factor order) for ``factor``'s matrix.

    The columns of ``B^{-1}`` at every patch node come from one batched solve
    with the kernel's float32 triangles; each ``G`` is symmetrised and
    inverted in float64.
    """
    n, s = stim.shape
    rows = [np.flatnonzero(stim[:, c]) for c in range(s)]
    sizes = np.array([len(r) for r in rows], np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    flat = np.concatenate(rows).astype(np.int64)
    unit = np.zeros((n, -(-len(flat) // LANES) * LANES), np.float32)
    unit[flat, np.arange(len(flat))] = 1.0
    _solve_columns(factor.triangles, unit)
    inverse = []
    for c in range(s):
        G = unit[rows[c]][:, offsets[c] : offsets[c + 1]].astype(float)
        inverse.append(np.linalg.inv(0.5 * (G + G.T)).ravel() if sizes[c] else np.zeros(0))
    return Patches(
        offsets,
        flat,
        np.concatenate([[0], np.cumsum(sizes**2)]).astype(np.int64),
        np.concatenate(inverse).astype(np.float32),
    )


@njit(inline="always", **_STRICT)
def _explicit(u, v, up, vp, fp, gp, rhs, mass, a, restart, dt, cell):  # pragma: no cover - compiled
    """The explicit half of a step: ``rhs`` of the solve, ``v`` advanced; ``up, vp, fp, gp`` become step n's.

    A ``restart`` step is IMEX Euler (``rhs = M (u + dt f)``, ``v += dt g``),
    the others SBDF2; ``f``, ``g`` are the cell model's rates without diffusion
    (:func:`~simgen.solver.cells.ops.cell_rates`, ``cell`` its constants).
    LANES columns at a time (the width is a multiple of LANES).
    """
    n, s = u.shape
    two, half = vsplat(np.float32(2.0)), vsplat(np.float32(0.5))
    three, four = vsplat(np.float32(3.0)), vsplat(np.float32(4.0))
    vdt, vcell = vsplat(dt), splat(cell)
    for i in range(n):
        ai, mi = vsplat(a[i]), vsplat(mass[i])
        for o in range(i * s, i * s + s, LANES):
            ui, vi = vload(u, o), vload(v, o)
            f, g = cell_rates(ui, vi, None, ai, vcell)
            if restart:
                vstore(rhs, o, mi * (ui + vdt * f))
                vstore(v, o, vi + vdt * g)
            else:
                vstore(rhs, o, mi * (two * ui - half * vload(up, o) + vdt * (two * f - vload(fp, o))))
                vstore(v, o, (four * vi - vload(vp, o) + two * vdt * (two * g - vload(gp, o))) / three)
            vstore(up, o, ui)
            vstore(vp, o, vi)
            vstore(fp, o, f)
            vstore(gp, o, g)


@njit(inline="always", **_STRICT)
def _substitute(ptr, idx, values, x, i, s):  # pragma: no cover - compiled
    """``x[i] - sum_p values[p] x[idx[p]]`` over row ``i`` of a triangle, written to ``x[i]``, LANES columns at a time.

    Four partial sums (entries ``p`` taken in turn) keep four multiply-adds in
    flight; every column adds in the same order, whatever ``s`` (a multiple of LANES).
    """
    start, end = ptr[i], ptr[i + 1]
    zero = vsplat(np.float32(0.0))
    for c in range(0, s, LANES):
        a0, a1, a2, a3 = vload(x, i * s + c), zero, zero, zero
        p = start
        while p + 4 <= end:
            a0 = vfma(vsplat(-values[p]), vload(x, idx[p] * s + c), a0)
            a1 = vfma(vsplat(-values[p + 1]), vload(x, idx[p + 1] * s + c), a1)
            a2 = vfma(vsplat(-values[p + 2]), vload(x, idx[p + 2] * s + c), a2)
            a3 = vfma(vsplat(-values[p + 3]), vload(x, idx[p + 3] * s + c), a3)
            p += 4
        if p < end:
            a0 = vfma(vsplat(-values[p]), vload(x, idx[p] * s + c), a0)
        if p + 1 < end:
            a1 = vfma(vsplat(-values[p + 1]), vload(x, idx[p + 1] * s + c), a1)
        if p + 2 < end:
            a2 = vfma(vsplat(-values[p + 2]), vload(x, idx[p + 2] * s + c), a2)
        vstore(x, i * s + c, (a0 + a1) + (a2 + a3))


@njit(inline="always", **_STRICT)
def _solve(triangles, x):  # pragma: no cover - compiled
    """``x <- U^{-1} L^{-1} x`` in place (``x`` C-contiguous, its width a multiple of LANES).

    ``triangles``: :attr:`Factor.triangles`.
    """
    lower_ptr, lower_idx, lower, upper_ptr, upper_idx, upper, inverse_diagonal = triangles
    n, s = x.shape
    for i in range(n):
        _substitute(lower_ptr, lower_idx, lower, x, i, s)
    for i in range(n - 1, -1, -1):
        _substitute(upper_ptr, upper_idx, upper, x, i, s)
        d = inverse_diagonal[i]
        for c in range(s):
            x[i, c] *= d


@njit(nogil=True, cache=True, **_STRICT)
def _solve_columns(triangles, x):  # pragma: no cover - compiled
    """:func:`_solve` as a kernel of its own."""
    _solve(triangles, x)


@njit(inline="always", **_STRICT)
def _multipliers(x, col0, offsets, rows, squares, inverse, z):  # pragma: no cover - compiled
    """``z``: zero but for each column's multipliers ``G^{-1} (1 - x_C)`` on its patch rows ``C``.

    Column ``c`` of ``x`` is column ``col0 + c`` of the run (its patch in ``offsets``, ``rows``, ...).
    """
    z[:] = np.float32(0.0)
    one = np.float32(1.0)
    for c in range(x.shape[1]):
        o, q = offsets[col0 + c], squares[col0 + c]
        m = offsets[col0 + c + 1] - o
        for r in range(m):
            acc = np.float32(0.0)
            for t in range(m):
                acc = fma(inverse[q + r * m + t], one - x[rows[o + t], c], acc)
            z[rows[o + r], c] = acc


@njit(inline="always", **_STRICT)
def _hold(x, z, col0, offsets, rows):  # pragma: no cover - compiled
    """``x += z`` (the Dirichlet correction), then the patch rows exactly 1."""
    n, s = x.shape
    for i in range(n):
        for c in range(s):
            x[i, c] += z[i, c]
    for c in range(s):
        for t in range(offsets[col0 + c], offsets[col0 + c + 1]):
            x[rows[t], c] = np.float32(1.0)


@njit(inline="always", **_STRICT)
def _record(u_old, u_new, act, t0, dt, thr):  # pragma: no cover - compiled
    """First threshold crossings in this step: time interpolated linearly between the two states.

    Lanes are checked a vector at a time; the rare vectors with a crossing are recorded one column at a time.
    """
    n, s = u_old.shape
    vthr = vsplat(thr)
    for i in range(n):
        for c0 in range(0, s, LANES):
            o = i * s + c0
            if vany((vload(u_old, o) < vthr) & (vload(u_new, o) >= vthr)):
                for c in range(c0, c0 + LANES):
                    ui, un = u_old[i, c], u_new[i, c]
                    if ui < thr <= un and act[i, c] < np.float32(0.0):
                        act[i, c] = t0 + dt * (thr - ui) / (un - ui)


@njit(inline="always", **_STRICT)
def _output(u, perm, col0, frames, frame):  # pragma: no cover - compiled
    """Frame ``frame`` of the block's columns (``col0`` the first) in mesh order; padding columns are not output."""
    n, s = u.shape
    for i in range(n):
        j = perm[i]
        for c in range(min(s, frames.shape[0] - col0)):
            frames[col0 + c, frame, j] = u[i, c]


@njit(nogil=True, cache=True, **_STRICT)
def _run_block(operands, mass, a, u0, col0, counts, params, cell, perm, frames, act):  # pragma: no cover - compiled
    """Every step of one block of columns, ``col0`` its first column in the run (see :func:`run_imex`).

    ``operands = (step triangles, step patch tables, start triangles, start patch tables)``.
    """
    step_triangles, step_held, start_triangles, start_held = operands
    stim_steps, n_steps, out_every = counts
    dt, thr, v_rest = params
    u = u0.copy()
    rhs, v, up, vp = np.zeros_like(u), np.full_like(u, v_rest), np.zeros_like(u), np.zeros_like(u)
    fp, gp, z = np.zeros_like(u), np.zeros_like(u), np.zeros_like(u)
    frame = 0
    for step in range(n_steps):
        restart = step == 0 or step == stim_steps  # a one-step start wherever the stimulus switches
        triangles, held = (start_triangles, start_held) if restart else (step_triangles, step_held)
        _explicit(u, v, up, vp, fp, gp, rhs, mass, a, restart, dt, cell)
        _solve(triangles, rhs)
        if step < stim_steps:
            offsets, rows, squares, inverse = held
            _multipliers(rhs, col0, offsets, rows, squares, inverse, z)
            _solve(triangles, z)
            _hold(rhs, z, col0, offsets, rows)
        _record(u, rhs, act, np.float32(step) * dt, dt, thr)
        u, rhs = rhs, u
        if (step + 1) % out_every == 0:
            _output(u, perm, col0, frames, frame)
            frame += 1


def run_imex(
    factors: Factors,
    a: NDArray[np.float32],
    stim: NDArray[np.bool_],
    counts: tuple[int, int, int],
    params: tuple[np.float32, ...],
    cell: tuple,
    frames: NDArray[np.float32],
    act: NDArray[np.float32],
    width: int,
    threads: int = 1,
    initial: NDArray[np.float32] | None = None,
) -> None:
    """Integrate an IMEX-Euler step, then SBDF2 steps, of every column of the (N, S) stimulus mask ``stim``.

    Arrays are in factor order (``factors.perm``). ``counts = (stim_steps,
    n_steps, out_every)``: steps the stimulus holds, steps in all, steps per
    output frame; ``params = (dt, thr, v_rest)`` float32 (the time step, the
    activation threshold, ``v`` at rest); ``cell``: the cell model's constants
    (:func:`~simgen.solver.cells.ops.cell_rates`). ``a`` is the
    excitability; ``frames`` (S, F, N) receives ``u`` in mesh order every
    ``out_every`` steps; ``act`` (N, S; -1 = never, 0 on the patches) the
    first crossings of ``thr``. ``width``: columns integrated together, a
    multiple of :data:`~simgen.solver.simd.LANES`, in blocks spread over
    ``threads`` threads (the result depends on neither). ``initial``: ``u`` at ``t = 0`` (N, S) instead of
    1 on the patches and 0 elsewhere (``v`` starts at ``v_rest``).
    """
    s = stim.shape[1]
    padded, u0, block_act = padded_blocks(stim, act, width, initial)
    operands = tuple(
        part for factor in (factors.step, factors.start) for part in (factor.triangles, patches(factor, padded).tables)
    )
    counts = tuple(int(c) for c in counts)

    def run_block(start: int) -> None:
        columns = slice(start, start + width)
        block = np.ascontiguousarray(block_act[:, columns])
        u_block = np.ascontiguousarray(u0[:, columns])
        _run_block(operands, factors.mass, a, u_block, start, counts, params, cell, factors.perm, frames, block)
        block_act[:, columns] = block

    each_block(padded.shape[1], width, threads, run_block)
    act[:] = block_act[:, :s]


def padded_blocks(
    stim: NDArray[np.bool_], act: NDArray[np.float32], width: int, initial: NDArray[np.float32] | None
) -> tuple[NDArray[np.bool_], NDArray[np.float32], NDArray[np.float32]]:
    """The (N, S) mask ``stim`` padded to whole blocks of ``width`` columns (the padding stays at rest),
    ``u`` at ``t = 0`` (``initial``, else 1 on the patches) and ``act`` in that width."""
    n, s = stim.shape
    padded = np.zeros((n, -(-s // width) * width), bool)
    padded[:, :s] = stim
    u0 = padded.astype(np.float32)
    if initial is not None:
        u0[:, :s] = initial
    block_act = np.full(padded.shape, -1.0, np.float32)
    block_act[:, :s] = act
    return padded, u0, block_act


def each_block(columns: int, width: int, threads: int, run_block: Callable[[int], None]) -> int:
    """``run_block(start)`` for each block of ``width`` of the ``columns``, on up to ``threads`` threads
    (the kernels release the GIL); the number of blocks."""
    starts = range(0, columns, width)
    if threads > 1 and len(starts) > 1:
        with ThreadPoolExecutor(min(threads, len(starts)), thread_name_prefix="simgen-imex") as pool:
            list(pool.map(run_block, starts))
    else:
        for start in starts:
            run_block(start)
    return len(starts)
