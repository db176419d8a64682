"""The explicit-Euler steps of :mod:`simgen.solver.kernels` in torch, on any torch device.

:class:`TorchKernel` takes the numba kernel's inputs (the off-diagonal CSR
part and diagonal of the diffusion operator, excitability, stimulus,
constants, node permutation) and gives its outputs (frames in mesh node
order, interpolated first-crossing times) for all sites of a subject at once:
the state is one (N, S) float32 matrix per variable. A step is

1. ``lap = A u``: one sparse CSR times dense product (``torch.sparse_csr_tensor``;
   cuSPARSE on CUDA), the diagonal stored in ``A``;
2. the reaction, the Euler update of ``u`` and ``v`` and the activation
   record of :func:`step`, elementwise (fused into one kernel by
   ``torch.compile`` where :func:`compiles_on` says so);
3. nodes stimulated in that column held at ``u = 1`` during the first ``stim_steps`` steps;

and every ``out_every`` steps ``u`` is copied to the host (:class:`_FrameSink`),
so the device holds the state, never the (S, F, N) output. The arithmetic and
its order are the numba kernel's, float32 throughout; the sums of the sparse
product run in another order and without fused multiply-adds, so results
agree with it to rounding that grows over the steps (docs/solver-backends.md
gives the measured differences), not bitwise.

With the RKC2 stage table of :func:`simgen.solver.rkc_kernel.coefficients`
(``stages``), each step is instead the stages of :mod:`simgen.solver.rkc_kernel`,
one sparse product and an elementwise update (eager) per stage.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import scipy.sparse as sp
import torch
from numpy.typing import NDArray

from shared.errors import InputError
from simgen.solver.cells.ops import cell_rates

__all__ = ["TorchKernel", "step", "compiles_on", "torch_device", "cpu_threads", "tensors"]


def torch_device(device: str | torch.device | None) -> torch.device:
    """``device`` as a :class:`torch.device`; ``None``: ``cuda`` where torch finds a GPU, else ``cpu``.

    Raises :class:`InputError` for a name torch does not know and for a CUDA
    device this process cannot see.
    """
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise InputError(f"unknown torch device {device!r} (use 'cpu', 'cuda' or 'cuda:N'): {exc}") from None
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise InputError(f"no CUDA device: torch {torch.__version__} finds no GPU for device {str(dev)!r}")
        if dev.index is not None and dev.index >= count:
            raise InputError(f"no CUDA device {dev.index}: torch finds {count} GPU(s) (cuda:0..cuda:{count - 1})")
    elif dev.type != "cpu":
        raise InputError(f"device {str(dev)!r} is not supported by the torch solver: use 'cpu' or 'cuda[:N]'")
    return dev


@contextmanager
def cpu_threads(device: torch.device, threads: int) -> Iterator[None]:
    """``threads`` torch threads for the block where ``device`` is the CPU; torch's setting is restored after."""
    saved = torch.get_num_threads()
    if device.type == "cpu":
        torch.set_num_threads(max(1, int(threads)))
    try:
        yield
    finally:
        torch.set_num_threads(saved)


def compiles_on(device: torch.device) -> bool:
    """Whether :func:`step` runs through ``torch.compile`` by default: on CUDA only.

    On CUDA the eager step is about twenty kernel launches of a few
    microseconds each, the compiled one a single fused kernel. On the CPU the
    torch backend checks the numba kernel rather than replacing it, and the
    eager step is kept: on a 2-core AMD EPYC VM (AVX-512; 2,000-node LV, 200 sites,
    one thread) the compiled step made the run 3.7-4.1 ns per node-step
    against 13-15 eager, but with inductor's cache empty the first run took
    18 s (4-7 s with it warm), longer than the tests may wait
    (``bench/solver.py --backend torch --compile on``; docs/solver-backends.md).
    """
    return device.type == "cuda"


def step(
    u: torch.Tensor,
    v: torch.Tensor,
    lap: torch.Tensor,
    act: torch.Tensor,
    a: torch.Tensor,
    t0: torch.Tensor,
    c: tuple[torch.Tensor, torch.Tensor],
    cell: tuple[torch.Tensor, ...],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One Euler step from the diffusion term ``lap``: ``(u, v, act) -> (u', v', act')``.

    ``a``: (N, 1) excitability; ``t0``: the step's start time (0-d);
    ``c = (dt, thr)`` and ``cell``, the cell model's constants, as 0-d float32
    tensors (so that a compiled step serves every subject). The rates are the
    cell model's (:func:`~simgen.solver.cells.ops.cell_rates`, the numba
    kernels' text); ``act`` takes the interpolated time at which ``u`` first
    crosses ``thr`` (it is -1 until then).
    """
    dt, thr = c
    du, dv = cell_rates(u, v, lap, a, cell)
    un = u + dt * du
    crossed = (u < thr) & (un >= thr) & (act < 0.0)
    return un, v + dt * dv, torch.where(crossed, t0 + dt * (thr - u) / (un - u), act)


class _FrameSink:
    """Writes frames (S, N) of device tensors into the host (S, F, N) output.

    On CUDA each frame goes into one of two pinned buffers by an asynchronous
    copy and reaches the output when that buffer is next needed (or at
    :meth:`close`), so the device keeps stepping meanwhile; on the CPU frames
    are written directly.
    """

    def __init__(self, frames: NDArray[np.float32], device: torch.device):
        self.frames = torch.from_numpy(frames)
        self.device = device
        self.staged: list[tuple[int, torch.cuda.Event] | None] = [None, None]  # frame index, copy done
        shape = self.frames[:, 0].shape
        on_cuda = device.type == "cuda"
        self.buffers = [torch.empty(shape, dtype=torch.float32, pin_memory=True) for _ in range(2)] if on_cuda else []

    def put(self, index: int, frame: torch.Tensor) -> None:
        """Frame ``index`` (S, N) of the output."""
        if not self.buffers:
            self.frames[:, index] = frame
            return
        slot = index % 2
        self._drain(slot)
        self.buffers[slot].copy_(frame, non_blocking=True)
        event = torch.cuda.Event()
        event.record(torch.cuda.current_stream(self.device))
        self.staged[slot] = (index, event)

    def close(self) -> None:
        """Wait for the frames in flight."""
        for slot in range(len(self.staged)):
            self._drain(slot)

    def _drain(self, slot: int) -> None:
        if self.staged[slot] is not None:
            index, event = self.staged[slot]
            event.synchronize()
            self.frames[:, index] = self.buffers[slot]
            self.staged[slot] = None


class TorchKernel:
    """The diffusion operator, excitability and node order of one subject on a torch device.

    Parameters are those of :func:`simgen.solver.kernels.run_blocks`:
    ``indptr, indices, data, diag`` the off-diagonal CSR part and diagonal of
    the (renumbered) operator, ``a`` (N,) excitability, ``perm`` (N,) the mesh
    node of each row. ``compile``: run :func:`step` through ``torch.compile``
    (``None``: :func:`compiles_on`); a compile that fails falls back to the
    eager step with a warning.
    """

    def __init__(
        self,
        indptr: NDArray[np.int64],
        indices: NDArray[np.int64],
        data: NDArray[np.float32],
        diag: NDArray[np.float32],
        a: NDArray[np.float32],
        perm: NDArray[np.int64],
        device: str | torch.device | None = None,
        compile: bool | None = None,
    ):
        self.device = torch_device(device)
        n = len(diag)
        full = (sp.csr_matrix((data, indices, indptr), shape=(n, n)) + sp.diags(diag)).tocsr()
        full.sort_indices()
        index = torch.int32 if full.nnz < 2**31 else torch.int64  # half the index bytes per step
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta", UserWarning)
            self.operator = torch.sparse_csr_tensor(
                torch.from_numpy(full.indptr.astype(np.int64)).to(index),
                torch.from_numpy(full.indices.astype(np.int64)).to(index),
                torch.from_numpy(full.data.astype(np.float32)),
                size=(n, n),
                check_invariants=True,
            ).to(self.device)
        self.nnz = full.nnz
        self.a = torch.from_numpy(np.asarray(a, np.float32)).reshape(n, 1).to(self.device)
        self.inverse_perm = torch.from_numpy(np.argsort(perm)).to(self.device)
        self.compiled = compiles_on(self.device) if compile is None else bool(compile)
        self._step: Callable = torch.compile(step, dynamic=True) if self.compiled else step

    def run(
        self,
        u_init: NDArray[np.float32],
        stim: NDArray[np.bool_],
        counts: tuple[int, int, int],
        params: tuple[np.float32, np.float32, np.float32],
        cell: tuple,
        frames: NDArray[np.float32],
        act: NDArray[np.float32],
        threads: int = 1,
        stages: NDArray[np.float32] | None = None,
    ) -> None:
        """Integrate ``n_steps`` steps of the (N, S) initial state ``u_init`` (``v`` starts at ``v_rest``).

        ``stim`` (N, S): nodes held at ``u = 1`` for the first ``stim_steps``
        steps; ``counts = (stim_steps, n_steps, out_every)``, ``params = (dt,
        thr, v_rest)`` and ``cell`` (the cell model's constants) as the numba
        kernel takes them. ``frames`` (S, F, N) receives ``u`` every
        ``out_every`` steps in mesh node order; ``act`` (N, S), -1 for never
        and 0 at stimulated nodes on entry, receives the activation times (both
        filled in place, as by the numba kernel). On the CPU torch runs
        ``threads`` threads meanwhile (its setting is restored afterwards).
        ``stages``: the (s, 5) RKC2 table; ``None`` is forward Euler.
        """
        stim_steps, n_steps, out_every = counts
        with cpu_threads(self.device, threads):
            dev = self.device
            u = torch.from_numpy(u_init).to(dev)
            v = torch.full_like(u, float(params[2]))
            hold = torch.from_numpy(stim).to(dev)
            act_t = torch.from_numpy(act).to(dev)
            c = tensors(params[:2], dev)
            constants = tensors(cell, dev)
            t0 = torch.arange(n_steps, dtype=torch.float32, device=dev) * c[0]  # float32(step) * dt, as numba
            sink = _FrameSink(frames, dev)
            table = None if stages is None else self._stage_table(stages, float(params[0]))
            for i in range(n_steps):
                if table is None:
                    lap = self.operator @ u
                    u, v, act_t = self._run_step(u, v, lap, act_t, self.a, t0[i], c, constants)
                else:
                    un, v = self._rkc_step(u, v, hold if i < stim_steps else None, table, constants)
                    crossed = (u < c[1]) & (un >= c[1]) & (act_t < 0.0)
                    u, act_t = un, torch.where(crossed, t0[i] + c[0] * (c[1] - u) / (un - u), act_t)
                if i < stim_steps:
                    u.masked_fill_(hold, 1.0)
                if (i + 1) % out_every == 0:
                    sink.put((i + 1) // out_every - 1, u.index_select(0, self.inverse_perm).T)
            sink.close()
            act[...] = act_t.cpu().numpy()

    def _rkc_step(
        self,
        u: torch.Tensor,
        v: torch.Tensor,
        hold: torch.Tensor | None,
        table: list[tuple[torch.Tensor, ...]],
        cell: tuple[torch.Tensor, ...],
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One RKC2 step ``(u, v) -> (u', v')`` through the stages of ``table`` (:meth:`_stage_table`);
        ``hold``: the stimulated nodes, set to ``u = 1`` in every stage (``None``: no stimulus)."""
        f0 = cell_rates(u, v, self.operator @ u, self.a, cell)
        prev2, prev, f = (u, v), (u, v), f0
        for j, (c0, mu, nu, mu_dt, gamma_dt) in enumerate(table):
            if j > 0:
                f = cell_rates(*prev, self.operator @ prev[0], self.a, cell)
            stage = tuple(
                c0 * y0 + mu * y1 + nu * y2 + mu_dt * fy + gamma_dt * fy0
                for y0, y1, y2, fy, fy0 in zip((u, v), prev, prev2, f, f0)
            )
            if hold is not None:
                stage[0].masked_fill_(hold, 1.0)
            prev2, prev = prev, stage
        return prev

    def _stage_table(self, stages: NDArray[np.float32], dt: float) -> list[tuple[torch.Tensor, ...]]:
        """Rows ``(1 - mu - nu, mu, nu, mu~ dt, gamma~ dt)`` of the RKC2 table as 0-d float32 tensors
        (the products in float32, as the numba kernel forms them)."""
        scaled = np.asarray(stages, np.float32).copy()
        scaled[:, 3:] *= np.float32(dt)
        return [row.unbind() for row in torch.from_numpy(scaled).to(self.device)]

    def _run_step(self, *args: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:func:`step`, compiled where chosen; a compile error switches this kernel to the eager step."""
        try:
            return self._step(*args)
        except Exception as exc:  # inductor/triton failures surface on the first call
            if self._step is step:
                raise
            warnings.warn(f"torch.compile of the solver step failed, running it eagerly: {exc}", stacklevel=2)
            self._step, self.compiled = step, False
            return step(*args)


def tensors(values: tuple, device: torch.device) -> tuple:
    """``values`` (float32 numbers, or a cell model's constants tuple) as 0-d float32 tensors on ``device``,
    in a tuple of the same class."""
    items = torch.tensor(tuple(map(float, values)), dtype=torch.float32, device=device).unbind()
    return type(values)(*items) if hasattr(values, "_fields") else tuple(items)
