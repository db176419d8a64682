"""Batched Aliev-Panfilov simulation of many stimulation sites on one subject.

A :class:`Simulator` assembles the diffusion operator of one mesh + tissue
once (nodes renumbered by reverse Cuthill-McKee for cache locality), picks a
stable time step, and runs any number of stimulation sites together as an
``N x S`` state matrix through the fused kernel of :mod:`simgen.solver.kernels`
(backend ``"numba"``, CPU) or the same steps in torch on any torch device
(:mod:`simgen.solver.torch_kernel`, backend ``"torch"``; docs/solver-backends.md).
The integrator is forward Euler, the stabilised second-order
Runge-Kutta-Chebyshev method of :mod:`simgen.solver.rkc_kernel` (``"rkc"``), or
the implicit-explicit SBDF2 method of :mod:`simgen.solver.imex_kernel`
(``"imex"``), whose step no element of the mesh limits; ``"auto"`` (the
default) picks the cheaper of Euler and IMEX on each mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import DTypeLike, NDArray
from scipy.sparse.csgraph import reverse_cuthill_mckee

from shared.capture import activated_fraction, started_wave
from shared.errors import ConfigError, InputError, TimeStepError, TissueError
from shared.fem import Geometry, element_gradients, lumped_mass, operator_from, stiffness_matrix
from shared.mesh import Mesh
from shared.tissue import TissueFields
from simgen.meshes.topology import edge_graph
from simgen.solver.backends import check_backend, resolve_backend
from simgen.solver.cells import APParams, CellModel
from simgen.solver.imex_cg import MAX_ITERATIONS, implicit_matrices, run_imex_cg
from simgen.solver.imex_kernel import Factor, factorise, run_imex
from simgen.solver.integrators import AUTO, check_integrator, choose_step
from simgen.solver.kernels import run_blocks
from simgen.solver.rkc_kernel import coefficients, run_blocks_rkc
from simgen.solver.simd import LANES
from simgen.solver.stimulus import STIMULUS_REGIONS, patch_mask
from simgen.solver.timestep import (
    cg_iterations,
    cg_solve_cost,
    cheaper_integrator,
    factor_solve_cost,
    largest_eigenvalue,
    stability_limit,
)

__all__ = [
    "STIMULUS_RADIUS",
    "SolverConfig",
    "SimulationResult",
    "Assembly",
    "assemble",
    "Simulator",
    "simulate",
    "healthy_fields",
]

#: Sites integrated together per block: a whole number of SIMD vectors wide, few blocks per thread
#: (`bench/solver.py --block-size` measures other choices on a machine).
BLOCK_SIZE = 128

#: Sites the IMEX kernels integrate together per block: their state (7-11 N x B float32 arrays) stays small.
IMEX_BLOCK = 32

#: How IMEX may solve its implicit systems: a sparse direct factor (:mod:`simgen.solver.imex_kernel`) or
#: Jacobi-preconditioned conjugate gradients (:mod:`simgen.solver.imex_cg`).
IMEX_SOLVES = ("factor", "cg")

#: Largest mesh whose IMEX solves may use a direct factor: above it the factor's fill makes CG cheaper
#: (at 5,000 nodes CG already is on the procedural LV) and factoring alone takes seconds.
DIRECT_SOLVE_NODES = 10_000

#: Default stimulus radius (mm): the patch launches a wave from every non-scar site of the procedural and real
#: hearts at 1k to 20k nodes (bench/convergence.py; docs/method.md, Convergence).
STIMULUS_RADIUS = 10.0
#: Most time steps a simulation may take (a ``dt`` that implies more is refused with its count).
MAX_STEPS = 1_000_000


@dataclass(frozen=True)
class SolverConfig:
    """Solver and output settings.

    ``model`` is the cell model (:mod:`simgen.solver.cells`: Aliev-Panfilov,
    the default, or Mitchell-Schaeffer); its rates run in every integrator and
    backend, its ``max_rate`` and ``dt_accuracy`` set their steps.

    Defaults are scaled for the default ~2,000-node LV (mean edge ~5.4 mm):
    ``diffusivity = 100 mm^2`` per time unit gives an Aliev-Panfilov front speed of
    ``sqrt(2 k D)(1/2 - a) = 14 mm`` per time unit (1.09 m/s) spanning ~20 mm
    (about four edges). The stimulus holds ``u = 1`` on a patch around the
    site for ``stimulus_duration`` time units (12.9 ms): the tissue within
    ``stimulus_radius`` mm, :data:`STIMULUS_RADIUS` when unset, of the shape
    ``stimulus_region`` (:data:`~simgen.solver.stimulus.STIMULUS_REGIONS`;
    ``None``: ``"ball"``, the Euclidean ball around the site). Both are
    lengths in mm, so the patch is the same piece of tissue at any mesh
    resolution, and it launches a wave from every site outside scar cores
    at every resolution measured (docs/method.md, Convergence). Stores
    record the radius and region that ran on each subject; subjects without
    the region record ran ``"geodesic"`` patches (edge paths) of 1.5 mean
    edge lengths, the default of stores built before these settings existed.
    55 frames every 0.6 time units (7.7 ms) cover 33 time units (426 ms): the
    whole activation and the start of repolarisation.

    ``backend`` (:data:`~simgen.solver.backends.BACKENDS`, see
    :class:`Simulator`) chooses the code that integrates, not the model:
    ``None`` means ``"numba"`` (``"numba"`` given is stored as ``None``) and is
    left out of a build spec's hash, so that stores built before the setting
    existed resume.

    ``integrator`` (:data:`~simgen.solver.integrators.INTEGRATORS`) changes the results: ``"euler"``
    (forward Euler at the stable step), ``"rkc"`` (RKC2 at the accuracy step
    with as many stages as the mesh's stiffness needs), ``"imex"`` (SBDF2 with
    implicit diffusion at :data:`~simgen.solver.timestep.DT_IMEX`, whatever
    the mesh), or ``"auto"``: Euler where it is cheaper than IMEX (procedural
    meshes of a few thousand nodes), else IMEX
    (:func:`~simgen.solver.timestep.cheaper_integrator`). With ``rkc``,
    ``imex`` and ``auto`` ``dt`` may exceed the Euler limit. ``None`` means
    ``"auto"`` (``"auto"`` given is stored as ``None``) and, like ``backend``,
    stays out of a spec's hash; a store
    records the integrator that ran on each subject, and a subject without
    that record (stores written before it existed) runs forward Euler.

    ``anisotropy``: the ratio ``D_l / D_t`` of conduction along and across the
    mesh's fibres (:attr:`shared.mesh.Mesh.fibres`; ``diffusivity`` is the
    along-fibre value, :mod:`shared.fem`), a front about
    ``sqrt(anisotropy)`` times faster along them; ``None`` (or 1): isotropic,
    and out of a spec's hash. Every integrator and backend takes it, through
    the assembled operator. ``sheet_anisotropy``: the ratio ``D_s / D_n`` of
    conduction along the mesh's sheets (:attr:`shared.mesh.Mesh.sheets`) and
    normal to them, on top of ``anisotropy`` (orthotropic tissue); ``None`` (or
    1): transversely isotropic about the fibres.
    """

    diffusivity: float = 100.0
    model: CellModel = field(default_factory=APParams)
    dt: float | None = None
    output_interval: float = 0.6
    frames: int = 55
    stimulus_radius: float | None = None
    stimulus_region: Literal["ball", "geodesic"] | None = None
    stimulus_duration: float = 1.0
    activation_threshold: float = 0.5
    backend: Literal["numba", "torch", "auto"] | None = None
    integrator: Literal["euler", "rkc", "imex", "auto"] | None = None
    anisotropy: float | None = None
    sheet_anisotropy: float | None = None

    def __post_init__(self) -> None:
        if not np.isfinite(self.diffusivity) or self.diffusivity <= 0:
            raise InputError(f"diffusivity must be finite and > 0 mm^2 per time unit, got {self.diffusivity}")
        if not np.isfinite(self.output_interval) or self.output_interval <= 0:
            raise InputError(f"output_interval must be > 0 time units, got {self.output_interval}")
        if int(self.frames) != self.frames or self.frames < 1:
            raise InputError(f"frames must be a positive integer, got {self.frames}")
        if self.stimulus_radius is not None and not (np.isfinite(self.stimulus_radius) and self.stimulus_radius >= 0):
            raise InputError(f"stimulus_radius must be >= 0 mm, got {self.stimulus_radius}")
        if self.stimulus_region is not None and self.stimulus_region not in STIMULUS_REGIONS:
            raise ConfigError(
                f"unknown stimulus_region {self.stimulus_region!r}; allowed: {', '.join(map(repr, STIMULUS_REGIONS))}"
            )
        if not np.isfinite(self.stimulus_duration) or self.stimulus_duration < 0:
            raise InputError(f"stimulus_duration must be >= 0 time units, got {self.stimulus_duration}")
        if not 0 < self.activation_threshold < 1:
            raise InputError(f"activation_threshold must be in (0, 1), got {self.activation_threshold}")
        for name in ("anisotropy", "sheet_anisotropy"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value >= 1):
                raise InputError(f"{name} must be a finite ratio >= 1, got {value}")
        if self.backend is not None:
            check_backend(self.backend)
        if self.integrator is not None:
            check_integrator(self.integrator)
        if self.dt is not None and np.isfinite(self.dt) and self.dt > 0 and self.duration / self.dt > MAX_STEPS:
            raise TimeStepError(
                f"time step dt={self.dt:g} implies {self.duration / self.dt:,.0f} steps ({self.duration:g} time units "
                f"of {self.frames} frames): more than {MAX_STEPS:,} is refused; give a larger dt or leave it unset "
                "(chosen for the mesh)"
            )
        defaults = (("integrator", AUTO), ("backend", "numba"), ("anisotropy", 1.0), ("sheet_anisotropy", 1.0))
        for name, default in defaults:  # a default: unset
            if getattr(self, name) == default:
                object.__setattr__(self, name, None)

    @property
    def duration(self) -> float:
        """Simulated time (time units)."""
        return self.frames * self.output_interval

    @property
    def radius(self) -> float:
        """The stimulus radius in mm: ``stimulus_radius``, or :data:`STIMULUS_RADIUS` when unset."""
        return STIMULUS_RADIUS if self.stimulus_radius is None else self.stimulus_radius

    @property
    def region(self) -> str:
        """The stimulus patch's shape: ``stimulus_region``, or ``"ball"`` when unset."""
        return self.stimulus_region or STIMULUS_REGIONS[0]


@dataclass(frozen=True)
class SimulationResult:
    """Outputs for S stimulation sites on an N-node mesh.

    ``u`` (S, T, N) float32 snapshots at ``times``; ``activation`` (S, N)
    float32 first crossing of the activation threshold (NaN = never).
    """

    sites: NDArray[np.int64]
    times: NDArray[np.float64]
    u: NDArray[np.float32]
    activation: NDArray[np.float32]
    dt: float

    @property
    def activated_fraction(self) -> NDArray[np.float64]:
        """(S,) share of the nodes each stimulus activated (:func:`shared.capture.activated_fraction`)."""
        return activated_fraction(self.activation)

    @property
    def started_wave(self) -> NDArray[np.bool_]:
        """(S,) whether each stimulus started a propagating wave (:func:`shared.capture.started_wave`)."""
        return started_wave(self.activated_fraction)


def healthy_fields(n_nodes: int, a: float = 0.15) -> TissueFields:
    """Uniform healthy tissue on ``n_nodes`` nodes."""
    return TissueFields(a=np.full(n_nodes, a), D=np.ones(n_nodes), label=np.zeros(n_nodes, np.int8))


class Assembly(NamedTuple):
    """The diffusion operator ``A = -M^{-1} K`` of one mesh + tissue, its largest eigenvalue, the
    integrator that runs (never ``"auto"``), its time step, steps per frame, operator products or solves
    per step (1 for Euler and IMEX), the stiffness matrix ``K`` and lumped mass, and for IMEX the factored
    implicit matrix where its solves cost less than CG's (else ``None``: CG)."""

    A: sp.csr_matrix
    lambda_max: float
    integrator: str
    dt: float
    steps_per_frame: int
    stages: int
    stiffness: sp.csr_matrix
    mass: NDArray[np.float64]
    factor: Factor | None = None


def assemble(
    mesh: Mesh,
    tissue: TissueFields,
    config: SolverConfig,
    geometry: Geometry | None = None,
    imex_solve: str | None = None,
) -> Assembly:
    """What checking a subject needs before anything is simulated (a :class:`Simulator` does more).

    ``geometry``: :func:`~shared.fem.element_gradients` of the mesh, when
    the caller assembles many tissues on one mesh. ``imex_solve``: ``"factor"``
    or ``"cg"`` for IMEX's implicit solves (``None``: the cheaper on this
    mesh, :data:`IMEX_SOLVES`). Raises
    :class:`~shared.errors.TissueError` if the fields do not match the mesh and
    :class:`~shared.errors.TimeStepError` for an unstable ``config.dt`` (Euler).
    """
    if imex_solve not in (None, *IMEX_SOLVES):
        raise ConfigError(f"imex_solve {imex_solve!r} is not one of {IMEX_SOLVES} (or None: the cheaper)")
    if len(tissue.a) != mesh.n_nodes:
        raise TissueError(f"tissue fields have {len(tissue.a)} nodes but mesh {mesh.name!r} has {mesh.n_nodes}")
    if geometry is None:
        geometry = element_gradients(mesh.points, mesh.cells)
    D = config.diffusivity * np.asarray(tissue.D, float)
    K = stiffness_matrix(mesh, D, geometry, config.anisotropy, config.sheet_anisotropy)
    mass = lumped_mass(mesh, geometry)
    A = operator_from(K, mass)
    lambda_max = largest_eigenvalue(A, mass)
    model, dt, interval = config.model, config.dt, config.output_interval
    integrator = config.integrator or AUTO
    matrices = (K, mass)

    def resolved(name: str) -> Assembly:
        return Assembly(A, lambda_max, name, *choose_step(name, lambda_max, model, dt, interval), *matrices)

    if integrator in ("rkc", "euler"):
        return resolved(integrator)
    if integrator == AUTO and dt is not None and dt < stability_limit(lambda_max, model.max_rate):
        return resolved("euler")
    imex_dt, imex_steps, _ = choose_step("imex", lambda_max, model, dt, interval)
    if integrator == AUTO and dt is None:
        euler = resolved("euler")
        if euler.steps_per_frame <= imex_steps:  # as few steps, each cheaper
            return euler
    factor, solve_cost = _imex_solve(K, mass, imex_dt, imex_solve)
    if integrator == AUTO and dt is None:
        if cheaper_integrator(euler.steps_per_frame, A.nnz, imex_steps, solve_cost, mesh.n_nodes) == "euler":
            return euler
    return Assembly(A, lambda_max, "imex", imex_dt, imex_steps, 1, *matrices, factor)


def _imex_solve(
    K: sp.csr_matrix, mass: NDArray[np.float64], dt: float, imex_solve: str | None
) -> tuple[Factor | None, float]:
    """IMEX's implicit solves: a direct factor, or CG (``None``), and the estimated work of one solve.

    ``imex_solve`` ``None`` takes the cheaper: the factor only up to
    :data:`DIRECT_SOLVE_NODES` nodes, where its fill is small.
    """
    n = len(mass)
    cg = cg_solve_cost(cg_iterations(dt, K.diagonal(), mass), K.nnz, n)
    if imex_solve == "cg" or (imex_solve is None and n > DIRECT_SOLVE_NODES):
        return None, cg
    factor = factorise(K, mass, dt)
    direct = factor_solve_cost(factor.nnz)
    return (factor, direct) if direct <= cg or imex_solve == "factor" else (None, cg)


class Simulator:
    """Operator, time step and node ordering of one mesh + tissue, reusable across runs.

    ``backend`` (default: ``config.backend``, else ``"numba"``) and ``device``
    (torch only; ``None``: ``cuda`` where torch finds a GPU, else ``cpu``)
    choose what integrates (:func:`~simgen.solver.backends.resolve_backend`):
    ``"numba"`` the fused CPU kernel, bitwise reproducible across threads and
    blocks; ``"torch"`` the same steps in torch, equal to numba within float32
    rounding (docs/solver-backends.md); ``"auto"`` torch on CUDA where a GPU
    is present, else numba. ``compile``: run the torch step through
    ``torch.compile`` (``None``: on CUDA only,
    :func:`simgen.solver.torch_kernel.compiles_on`). :attr:`integrator` is
    the one that runs (``config.integrator`` with ``"auto"`` resolved on this
    mesh); :attr:`stages` counts the operator products per time step (1 for
    Euler; for IMEX the solves, 2 while the stimulus holds). ``imex_solve``
    (numba only): ``"factor"`` or ``"cg"`` (``None``: the cheaper on this mesh;
    :attr:`imex_solve` says which runs).
    """

    def __init__(
        self,
        mesh: Mesh,
        tissue: TissueFields | None = None,
        config: SolverConfig | None = None,
        backend: str | None = None,
        device: str | None = None,
        compile: bool | None = None,
        imex_solve: str | None = None,
    ):
        self.mesh = mesh
        self.compile = compile
        self.config = config or SolverConfig()
        self.backend, self.device = resolve_backend(backend or self.config.backend or "numba", device)
        self._torch = None  # the TorchKernel, built on the first torch run
        self.tissue = tissue if tissue is not None else healthy_fields(mesh.n_nodes)
        assembly = assemble(mesh, self.tissue, self.config, imex_solve=imex_solve)
        A, self.lambda_max, self.integrator, self.dt, self.steps_per_frame, self.stages, K, mass, self.factor = assembly
        self._rkc = coefficients(self.stages).astype(np.float32) if self.integrator == "rkc" else None
        pattern = (abs(A) + abs(A).T).tocsr()
        self.perm = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
        self.inverse_perm = np.argsort(self.perm)
        Ap = sp.csr_matrix(A[self.perm][:, self.perm], dtype=np.float32)
        self._diag = Ap.diagonal().astype(np.float32)
        Ap.setdiag(0)
        Ap.eliminate_zeros()
        Ap.sort_indices()
        self._indptr = Ap.indptr.astype(np.int64)
        self._indices = Ap.indices.astype(np.int64)
        self._data = Ap.data.astype(np.float32)
        self._a = np.asarray(self.tissue.a, np.float32)[self.perm]
        self._mass = np.asarray(mass, np.float32)[self.perm]
        cg = self.integrator == "imex" and self.factor is None
        self._implicit = implicit_matrices(K, mass, self.dt, self.perm) if cg else None
        self._estimated_iterations = cg_iterations(self.dt, K.diagonal(), mass)
        #: Mean CG iterations per implicit solve in the last IMEX run by CG (``None`` before one).
        self.cg_iterations: float | None = None
        self.stimulus_radius = self.config.radius
        self._edge_graph = edge_graph(mesh)  # for the stimulus patches of every run

    @property
    def imex_solve(self) -> str | None:
        """How IMEX solves its implicit systems: ``"factor"``, ``"cg"``, or ``None`` for the other integrators."""
        if self.integrator != "imex":
            return None
        return "factor" if self.factor is not None else "cg"

    @property
    def entries_per_step(self) -> float:
        """Stored matrix entries one time step multiplies per site: the operator's times the stages (Euler,
        RKC2), or for IMEX the factor's (one solve; two while the stimulus holds) or the implicit matrix's
        times the products of a CG solve (its iterations, measured in the last run or else estimated by
        :func:`~simgen.solver.timestep.cg_iterations`, plus one for the first guess's residual)."""
        if self.imex_solve == "factor":
            return self.factor.nnz
        if self.imex_solve == "cg":
            iterations = self.cg_iterations
            if iterations is None:
                iterations = self._estimated_iterations
            return self._implicit.nnz * (iterations + 1.0)
        return (len(self._data) + len(self._diag)) * self.stages

    def run(
        self,
        sites: NDArray[np.integer],
        threads: int = 1,
        block_size: int = BLOCK_SIZE,
        centres: NDArray[np.floating] | None = None,
    ) -> SimulationResult:
        """Simulate every site in ``sites`` (node ids) in one batch on ``threads`` threads.

        Each site excites its patch: the nodes within ``stimulus_radius`` mm of it
        (:func:`~simgen.solver.stimulus.patch_mask`, of ``config.region``), or of
        its point in ``centres`` (S, 3) mm for sites given by position.
        """
        mask = patch_mask(self.mesh, sites, self.stimulus_radius, self._edge_graph, self.config.region, centres)
        return self.run_patches(mask, threads, block_size, sites=np.asarray(sites, np.int64))

    def run_patches(
        self,
        mask: NDArray[np.bool_],
        threads: int = 1,
        block_size: int = BLOCK_SIZE,
        sites: NDArray[np.int64] | None = None,
    ) -> SimulationResult:
        """Simulate one stimulus per column of the (N, S) boolean ``mask`` of excited nodes.

        With the numba backend sites are integrated in independent blocks of
        at most ``block_size`` columns, spread over ``threads`` threads; the
        result does not depend on either. The torch backend runs all columns
        as one state matrix on :attr:`device` (``threads`` torch threads on
        the CPU) and ignores ``block_size``.
        """
        cfg = self.config
        mask = np.asarray(mask, bool)
        if mask.ndim != 2 or mask.shape[0] != self.mesh.n_nodes or mask.shape[1] == 0:
            raise InputError(f"stimulus mask must have shape ({self.mesh.n_nodes}, S>0), got {mask.shape}")
        mask = mask[self.perm]
        s = mask.shape[1]
        constants = (
            (
                int(round(cfg.stimulus_duration / self.dt)),  # stim_steps
                cfg.frames * self.steps_per_frame,  # n_steps
                self.steps_per_frame,  # out_every
            ),
            tuple(map(np.float32, (self.dt, cfg.activation_threshold, cfg.model.resting_v))),
            cfg.model.constants(),
        )
        if self.integrator == "imex":
            u, act = (self._run_torch_imex if self.backend == "torch" else self._run_imex)(mask, constants, threads)
        elif self.backend == "torch":
            u, act = self._run_torch(mask, constants, threads)
        else:
            u, act = self._run_numba(mask, constants, threads, block_size)
        activation = act[:, self.inverse_perm]
        activation[activation < 0] = np.nan
        if not np.all(np.isfinite(u[:, -1])):
            raise InputError("simulation diverged (non-finite u); reduce dt or check the tissue fields")
        times = cfg.output_interval * np.arange(1, cfg.frames + 1)
        sites = np.full(s, -1, np.int64) if sites is None else sites
        return SimulationResult(sites, times, u, activation, self.dt)

    def _run_numba(
        self, mask: NDArray[np.bool_], constants: tuple, threads: int, block_size: int
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Frames (S, F, N) and activation (S, N, kernel row order) from :func:`run_blocks` (Euler) or
        :func:`run_blocks_rkc` in blocks of sites."""
        n, s = mask.shape
        n_blocks = max(min(int(threads), s), -(-s // block_size))
        width = -(-s // n_blocks)
        if width > 1:  # whole vectors: a column costs ~5x more on the kernel's scalar path than in a vector
            width = -(-width // LANES) * LANES  # (one site alone stays scalar: cheaper than a vector of 8 lanes)
        padded = np.zeros((n, n_blocks * width), bool)
        padded[:, :s] = mask
        stim = np.ascontiguousarray(padded.reshape(n, n_blocks, width).transpose(1, 0, 2))
        frames = page_aligned_empty((n_blocks, width, self.config.frames, n), np.float32)
        act = np.where(stim, np.float32(0.0), np.float32(-1.0))  # stimulated nodes activate at t = 0
        numba.set_num_threads(max(1, min(int(threads), n_blocks, numba.config.NUMBA_NUM_THREADS)))
        args = (self._indptr, self._indices, self._data, self._diag, self._a, stim.astype(np.float32), stim)
        if self._rkc is None:
            run_blocks(*args, *constants, self.perm, frames, act)
        else:
            run_blocks_rkc(*args, *constants, self.perm, frames, act, self._rkc)
        u = frames.reshape(n_blocks * width, self.config.frames, n)[:s]  # a view: no copy of the largest array
        return u, act.transpose(0, 2, 1).reshape(n_blocks * width, n)[:s]

    def _run_imex(
        self, mask: NDArray[np.bool_], constants: tuple, threads: int
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Frames (S, F, N) and activation (S, N, kernel row order) from :func:`run_imex` (factor) or
        :func:`run_imex_cg` on ``threads`` threads."""
        n, s = mask.shape
        frames = page_aligned_empty((s, self.config.frames, n), np.float32)
        threads = max(1, min(int(threads), s))
        per_thread = -(-s // threads)
        width = -(-min(per_thread, IMEX_BLOCK) // LANES) * LANES  # whole vectors
        if self.factor is None:
            act = np.where(mask, np.float32(0.0), np.float32(-1.0))
            args = (np.ascontiguousarray(mask), *constants, self.perm, frames, act, width, threads)
            solves, iterations, stalled = run_imex_cg(self._implicit, self._a, *args)
            if stalled:
                raise InputError(
                    f"{stalled} of {solves} implicit solves did not converge in {MAX_ITERATIONS} CG iterations: "
                    "the tissue's diffusivity or the mesh's spacing needs a smaller dt, or the Euler integrator"
                )
            self.cg_iterations = iterations / solves
            return frames, act.T
        to_factor = self.inverse_perm[self.factor.perm]  # kernel row of each factor row
        stim = np.ascontiguousarray(mask[to_factor])
        act = np.where(stim, np.float32(0.0), np.float32(-1.0))
        a = np.asarray(self.tissue.a, np.float32)[self.factor.perm]
        run_imex(self.factor, a, stim, *constants, frames, act, width, threads)
        kernel_act = np.empty((s, n), np.float32)
        kernel_act[:, to_factor] = act.T
        return frames, kernel_act

    def _torch_kernel(self):
        """The :class:`~simgen.solver.torch_kernel.TorchKernel` of this subject, built on first use."""
        if self._torch is None:
            from simgen.solver.torch_kernel import TorchKernel  # torch is imported on this path only

            self._torch = TorchKernel(
                self._indptr, self._indices, self._data, self._diag, self._a, self.perm, self.device, self.compile
            )
        return self._torch

    def _run_torch_imex(
        self, mask: NDArray[np.bool_], constants: tuple, threads: int
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Frames (S, F, N) and activation (S, N, kernel row order) from IMEX steps in torch (CG solves)."""
        from simgen.solver.torch_imex import run_imex_torch

        n, s = mask.shape
        frames = page_aligned_empty((s, self.config.frames, n), np.float32)
        act = np.where(mask, np.float32(0.0), np.float32(-1.0))
        run_imex_torch(self._torch_kernel(), self._mass, mask, *constants, frames, act, threads)
        return frames, act.T

    def _run_torch(
        self, mask: NDArray[np.bool_], constants: tuple, threads: int
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Frames (S, F, N) and activation (S, N, kernel row order) from the torch kernel, built on first use."""
        self._torch_kernel()
        n, s = mask.shape
        frames = page_aligned_empty((s, self.config.frames, n), np.float32)
        act = np.where(mask, np.float32(0.0), np.float32(-1.0))
        self._torch.run(mask.astype(np.float32), mask, *constants, frames, act, threads=threads, stages=self._rkc)
        return frames, act.T


def page_aligned_empty(shape: tuple[int, ...], dtype: DTypeLike) -> NDArray:
    """``np.empty`` whose data starts on a 4096-byte page: a dataset build writes its chunk files
    straight from such memory with direct I/O (:func:`simgen.store.chunk_files.write_checksummed`)."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(nbytes + 4096, np.uint8)
    offset = -raw.ctypes.data % 4096
    return raw[offset : offset + nbytes].view(dtype).reshape(shape)


def simulate(
    mesh: Mesh,
    sites: NDArray[np.integer],
    tissue: TissueFields | None = None,
    config: SolverConfig | None = None,
    threads: int = 1,
) -> SimulationResult:
    """One-call form of ``Simulator(mesh, tissue, config).run(sites, threads)``."""
    return Simulator(mesh, tissue, config).run(sites, threads)
