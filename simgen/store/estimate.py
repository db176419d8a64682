"""What a build will take, worked out before anything is written: disk, memory per worker, time.

:func:`estimate_build` sizes a checked :class:`~simgen.store.manifest.Plan`:

* **disk**: every array of the layout at its stored chunk shape (a subject's
  last chunk is stored whole), results scaled by the compression ratio
  measured by ``bench/build.py`` (uncompressed: exact), plus metadata;
* **memory per worker**: the peak of one task: the worker process itself,
  the frames buffer of the chunk being simulated and of the one being
  written, the solver state, and the assembled operators of the subjects a
  worker keeps (``deploy/README.md`` measures the same terms);
* **time**: a short calibration, a few frames of the first subject's first
  chunk single-threaded, scaled by nodes x time steps x sites of every task.

:func:`check_resources` refuses a build whose task outgrows the workers'
memory limit or whose store outgrows the free disk space.
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from shared.errors import InputError
from shared.schema import ECG_ARRAYS, MESH_ARRAYS, SUBJECT_ARRAYS
from simgen.solver.simd import LANES
from simgen.solver.simulate import BLOCK_SIZE, Simulator
from simgen.store import location
from simgen.store.layout import subject_shapes
from simgen.store.manifest import Plan, SubjectSetup
from simgen.store.worker import SUBJECTS_KEPT

__all__ = ["BuildEstimate", "ResourceError", "estimate_build", "check_resources", "worker_memory_limit", "human"]

#: Stored bytes of ``u`` and ``activation`` per raw byte (bench/build.py on the paper store).
COMPRESSION_RATIO = {"none": 1.0, "blosc": 0.71, "zstd": 0.86}

#: Resident memory of a worker process besides its chunks: 160-170 MiB of imports (distributed, numba, zarr,
#: simgen; deploy/README.md) and ~70 MiB its first task loads (compiled kernel, codecs, store handles).
WORKER_BASE_BYTES = 240 * 2**20

#: Bytes of an array's or group's ``zarr.json``, a generous mean, and of the root's attributes (spec,
#: provenance, statistics); the root's ``zarr.json`` holds a consolidated copy of every other one.
METADATA_BYTES = 1024
ROOT_BYTES = 16 * 2**10

#: Frames simulated by the time calibration (at most).
CALIBRATION_FRAMES = 3


class ResourceError(InputError):
    """A build needs more memory per worker or more disk space than there is."""


@dataclass(frozen=True)
class BuildEstimate:
    """The plan of a build as printed before it starts; sizes in bytes, time in seconds."""

    meshes: dict[str, tuple[int, int]]  # mesh id -> (nodes, sites)
    settings: int
    subjects: int
    tasks: int
    simulations: int
    frames: int
    disk: int
    task_memory: int
    seconds: float | None  # simulation time on ``workers`` workers; None without calibration
    workers: int
    memory_limit: int | None  # per worker; None when unknown or unlimited
    store_bytes: int  # already in the store (a resumed build)
    free: int | None  # free bytes where the store goes; None when unknown (object stores)

    def lines(self) -> list[str]:
        """The plan, a line per fact."""
        meshes = [f"{m} ({n} nodes, {s} sites)" for m, (n, s) in list(self.meshes.items())[:4]]
        if len(self.meshes) > 4:
            meshes.append(f"... {len(self.meshes) - 4} more")
        limit = "unknown" if self.memory_limit is None else human(self.memory_limit)
        free = "unknown" if self.free is None else human(self.free)
        resumed = f", {human(self.store_bytes)} already in the store" if self.store_bytes else ""
        when = f"~{_duration(self.seconds)} of simulation" if self.seconds is not None else "not measured"
        return [
            f"meshes: {', '.join(meshes)}",
            f"subjects: {self.subjects} ({len(self.meshes)} mesh(es) x {self.settings} tissue setting(s))",
            f"simulations: {self.simulations} in {self.tasks} task(s), {self.frames} frames each",
            f"disk: ~{human(self.disk)}{resumed}; free: {free}",
            f"memory per worker: ~{human(self.task_memory)} per task; worker limit: {limit}",
            f"time: {when} on {self.workers} worker(s)",
        ]


def human(n: float) -> str:
    """Bytes as ``'12.3 MiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def _duration(seconds: float) -> str:
    """Seconds as ``'<1 s'``, ``'42 s'``, ``'12 min'`` or ``'3.5 h'``."""
    if seconds < 120:
        return f"{seconds:.0f} s" if seconds >= 1 else "<1 s"
    return f"{seconds / 60:.0f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def _columns(sites: int) -> int:
    """Columns the solver integrates for ``sites`` single-threaded: blocks of whole vectors."""
    blocks = -(-sites // BLOCK_SIZE)
    width = -(-sites // blocks)
    return blocks * (-(-width // LANES) * LANES if width > 1 else 1)


def _stored_bytes(shape: tuple[int, ...], chunks: tuple[int, ...], dtype: str) -> int:
    """Bytes of an array stored whole chunk by chunk, each with its 4-byte checksum."""
    n_chunks = math.prod(-(-s // c) for s, c in zip(shape, chunks))
    return n_chunks * (math.prod(chunks) * np.dtype(dtype).itemsize + 4)


def disk_bytes(plan: Plan) -> int:
    """Estimated bytes of the whole store of ``plan``."""
    spec = plan.spec
    ratio = COMPRESSION_RATIO[spec.output.compressor]
    total = ROOT_BYTES + 2 * METADATA_BYTES * (2 + len(plan.meshes) * (1 + len(MESH_ARRAYS)))
    per_mesh: dict[str, int] = {}
    for mesh_id, mesh in plan.meshes.items():
        n_sites = len(plan.sites[mesh_id])
        sets = sum(len(v) for v in mesh.node_sets.values()) + len(plan.electrodes[mesh_id])
        total += mesh.points.size * 8 + (mesh.cells.size + n_sites + sets) * 4
        subject = 0
        for name, (shape, chunks) in subject_shapes(mesh.n_nodes, n_sites, spec.output, spec.solver).items():
            stored = _stored_bytes(shape, chunks, {**SUBJECT_ARRAYS, **ECG_ARRAYS}[name].dtype)
            subject += round(stored * ratio) if name in ("u", "activation") else stored
        per_mesh[mesh_id] = subject + 2 * METADATA_BYTES * (1 + len(SUBJECT_ARRAYS))
    return total + sum(per_mesh[s.mesh_id] for s in plan.subjects)


def task_memory(plan: Plan) -> int:
    """Estimated peak memory of a worker running the largest task of ``plan``."""
    spec = plan.spec
    chunk, frames = spec.output.chunk_sites, spec.solver.frames
    peak = 0
    for mesh_id, mesh in plan.meshes.items():
        n, sites = mesh.n_nodes, min(chunk, len(plan.sites[mesh_id]))
        columns = _columns(sites)
        buffer = columns * frames * n * 4  # float32 frames, kept whole while its chunk is written
        copies = 2 + (spec.output.compressor != "none")  # simulating, being written, compressed
        state = columns * n * 21  # u0, u, v, activation (float32), stimulus (bool), activation out
        nnz = 2 * len(mesh.edges()) + n
        operator = nnz * 36 + n * 60  # float64 assembly, float32 + int64 CSR, edge graph, per-node vectors
        peak = max(peak, WORKER_BASE_BYTES + copies * buffer + state + SUBJECTS_KEPT * operator)
    return peak


def _calibrate(plan: Plan, setups: dict[str, SubjectSetup]) -> float:
    """Seconds per node, time step and solver column, single-threaded, on the first subject's first chunk."""
    subject = plan.subjects[0]
    mesh = plan.meshes[subject.mesh_id]
    frames = min(CALIBRATION_FRAMES, plan.spec.solver.frames)
    sim = Simulator(mesh, setups[subject.id].fields, replace(plan.spec.solver, frames=frames))
    sites = plan.sites[subject.mesh_id][: plan.spec.output.chunk_sites]
    sim.run(sites[:1])  # loads (or compiles) the kernel
    start = time.perf_counter()
    sim.run(sites)
    seconds = time.perf_counter() - start
    return seconds / (mesh.n_nodes * frames * sim.steps_per_frame * _columns(len(sites)))


def _seconds(plan: Plan, setups: dict[str, SubjectSetup], workers: int) -> float:
    """Simulation time of every task on ``workers`` workers, from :func:`_calibrate`."""
    per_unit = _calibrate(plan, setups)
    steps = plan.spec.solver.frames * np.array([setups[t.subject_id].steps_per_frame for t in plan.tasks])
    nodes = np.array([plan.meshes[plan.subject(t.subject_id).mesh_id].n_nodes for t in plan.tasks])
    columns = np.array([_columns(t.stop - t.start) for t in plan.tasks])
    return float(per_unit * (steps * nodes * columns).sum()) / max(1, min(workers, len(plan.tasks)))


def worker_memory_limit(scheduler: str | None, workers: int) -> tuple[int | None, int]:
    """``(memory limit per worker, worker count)``: a local cluster's share of this machine, or the
    smallest limit among the workers of ``scheduler`` (``None``: unlimited, or no worker there yet)."""
    if not scheduler:
        from distributed.system import MEMORY_LIMIT

        return MEMORY_LIMIT // workers, workers
    from distributed import Client

    try:
        with Client(scheduler, timeout="10s") as client:
            info = client.scheduler_info()["workers"].values()
    except OSError as exc:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    limits = [w.get("memory_limit") or 0 for w in info]
    return (min(limits) if limits and all(limits) else None), len(limits) or workers


def _free_bytes(store: str) -> int | None:
    """Free bytes of the file system a local store goes to; ``None`` for an object store."""
    if not location.is_local(store):
        return None
    path = Path(store)
    while not path.exists() and path != path.parent:
        path = path.parent
    return shutil.disk_usage(path).free


def estimate_build(
    plan: Plan,
    setups: dict[str, SubjectSetup],
    store: str,
    scheduler: str | None,
    workers: int,
    calibrate: bool = True,
) -> BuildEstimate:
    """The :class:`BuildEstimate` of building ``plan`` into ``store`` (a :func:`~simgen.store.location.store_location`).

    ``setups`` are :func:`~simgen.store.manifest.validate_plan`'s. Without
    ``calibrate`` nothing is simulated and the time is left out.
    """
    limit, n_workers = worker_memory_limit(scheduler, workers)
    spec = plan.spec
    return BuildEstimate(
        meshes={m: (mesh.n_nodes, len(plan.sites[m])) for m, mesh in plan.meshes.items()},
        settings=len(spec.settings()),
        subjects=len(plan.subjects),
        tasks=len(plan.tasks),
        simulations=sum(t.stop - t.start for t in plan.tasks),
        frames=spec.solver.frames,
        disk=disk_bytes(plan),
        task_memory=task_memory(plan),
        seconds=_seconds(plan, setups, n_workers) if calibrate else None,
        workers=n_workers,
        memory_limit=limit,
        store_bytes=location.size(store) if location.exists(store) else 0,
        free=_free_bytes(store),
    )


def check_resources(estimate: BuildEstimate) -> None:
    """Raise :class:`ResourceError` with the numbers when a task outgrows a worker or the store the disk.

    A worker is restarted once its memory passes Dask's ``terminate`` fraction
    of its limit; a resumed build needs only what is not in the store yet.
    """
    import dask

    if estimate.memory_limit is not None:
        usable = estimate.memory_limit * (dask.config.get("distributed.worker.memory.terminate") or 1.0)
        if estimate.task_memory > usable:
            raise ResourceError(
                f"a task needs ~{human(estimate.task_memory)} but a worker may use {human(usable)} "
                f"(memory limit {human(estimate.memory_limit)}): use fewer --workers, a smaller "
                "[output] chunk_sites or fewer [solver] frames, or workers with more memory"
            )
    needed = estimate.disk - estimate.store_bytes
    if estimate.free is not None and needed > estimate.free:
        raise ResourceError(
            f"the store needs ~{human(needed)} more disk space but only {human(estimate.free)} is free: "
            "free some space or choose another --store"
        )
