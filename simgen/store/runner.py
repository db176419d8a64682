"""Driver of a dataset build on a Dask cluster: plan, lay out, submit missing chunks, consolidate.

With no scheduler address a :class:`distributed.LocalCluster` of single-threaded
worker processes is started (BLAS and numba pinned to one thread each), or with
``gpus`` a :class:`GPUCluster` of one such process per GPU; with an address the
build runs on that existing cluster (``dask scheduler`` + ``dask worker``).
With ``gpus`` every task asks for the worker resource ``GPU=1``, so it runs on
a worker that owns a GPU, with the spec's torch backend (docs/solver-backends.md).
Rerunning the same build resumes it: only chunks whose ``done`` flag is unset
are submitted, so the result is identical to an uninterrupted build.
"""

from __future__ import annotations

import copy
import hashlib
import os
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from distributed import Client, LocalCluster, as_completed

from shared.errors import ConfigError, InputError
from simgen.solver.simulate import SolverConfig
from simgen.store import location
from simgen.store.card import short_card, store_facts
from simgen.store.estimate import BuildEstimate, check_resources, estimate_build
from simgen.store.layout import (
    LayoutState,
    chunk_tasks,
    consolidate,
    create_layout,
    layout_state,
    pending_tasks,
    write_statistics,
)
from simgen.store.location import store_location
from simgen.store.lock import LOCK_NAME, StoreLock, check_unlocked
from simgen.store.manifest import Plan, SubjectSetup, Task, make_plan, validate_plan
from simgen.store.spec import BuildSpec, spec_hash, spec_to_dict
from simgen.store.structure import refuse_damaged, structure_damage
from simgen.store.worker import flush_writes, run_task

__all__ = [
    "BuildFailed",
    "BuildReport",
    "GPUCluster",
    "cuda_devices",
    "gpu_workers",
    "check_gpus",
    "build",
    "plan_build",
    "store_state",
    "dry_run",
    "run_pending",
    "dask_client",
    "single_thread_env",
    "SINGLE_THREAD_ENV",
]

#: Environment for worker processes: one thread each for BLAS and numba.
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}


#: Seconds a local GPU cluster's workers may take to start (torch and CUDA load in each).
GPU_WORKER_START_S = 300


class BuildFailed(InputError):
    """Some tasks kept failing; finished chunks are kept."""


@dataclass
class BuildReport:
    """What one ``build`` call did."""

    store: str
    tasks_total: int
    tasks_run: int
    simulations: int
    seconds: float
    dashboard: str | None = None
    failed: list[str] = field(default_factory=list)


@contextmanager
def single_thread_env() -> Iterator[None]:
    """Set :data:`SINGLE_THREAD_ENV` for processes started inside the block, then restore."""
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def cuda_devices(gpus: int) -> list[str]:
    """The first ``gpus`` GPUs this process sees, as ``CUDA_VISIBLE_DEVICES`` names them.

    Raises :class:`InputError` ("no CUDA device") where torch finds fewer.
    """
    import torch

    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if count < gpus:
        found = f"only {count}" if count else "none"
        raise InputError(
            f"no CUDA device for --gpus {gpus}: it starts one worker per GPU, torch {torch.__version__} finds {found}"
        )
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    ids = [d.strip() for d in visible.split(",")] if visible else [str(i) for i in range(count)]
    return ids[:gpus]


class GPUCluster(LocalCluster):
    """A local cluster of one single-threaded worker process per GPU, like dask-cuda's ``LocalCUDACluster``.

    Worker ``gpu-<id>`` sees only GPU ``<id>`` (``CUDA_VISIBLE_DEVICES``, so
    it is ``cuda`` to torch there) and offers the resource ``GPU=1``; the
    workers share this machine's memory as a :class:`LocalCluster`'s do.
    """

    def __init__(self, devices: list[str], **kwargs):
        from distributed.system import MEMORY_LIMIT

        self.gpu_ids = list(devices)
        super().__init__(
            n_workers=0,
            threads_per_worker=1,
            processes=True,
            resources={"GPU": 1},
            memory_limit=MEMORY_LIMIT // len(self.gpu_ids),
            **kwargs,
        )
        self.scale(len(self.gpu_ids))

    def new_worker_spec(self) -> dict:
        """The spec of the next GPU's worker: the common one with that GPU made the only visible one."""
        device = next(d for d in self.gpu_ids if f"gpu-{d}" not in self.worker_spec)
        spec = copy.deepcopy(self.new_spec)
        spec["options"]["env"] = {"CUDA_VISIBLE_DEVICES": device}
        return {f"gpu-{device}": spec}


def gpu_workers(client: Client) -> list[str]:
    """Addresses of the workers that offer the resource ``GPU``."""
    info = client.scheduler_info()["workers"]
    return [address for address, w in info.items() if (w.get("resources") or {}).get("GPU", 0) >= 1]


@contextmanager
def dask_client(scheduler: str | None, workers: int, gpus: int = 0) -> Iterator[Client]:
    """A client of the cluster at ``scheduler``, or of a new local cluster of ``workers`` processes
    (with ``gpus``: of a :class:`GPUCluster` on the first ``gpus`` GPUs).

    With ``gpus`` the cluster at ``scheduler`` must have workers that offer
    the resource ``GPU`` (``dask worker ... --resources GPU=1``).
    """
    if scheduler:
        with Client(scheduler) as client:
            if gpus and not gpu_workers(client):
                raise InputError(
                    f"--gpus: no worker of the cluster at {scheduler} offers a GPU; start one worker per GPU "
                    "with CUDA_VISIBLE_DEVICES=<id> dask worker ... --resources GPU=1 (deploy/README.md)"
                )
            yield client
        return
    with single_thread_env():
        cluster = (
            GPUCluster(cuda_devices(gpus), dashboard_address=":0")
            if gpus
            else LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
        )
        with cluster, Client(cluster) as client:
            if gpus:
                client.wait_for_workers(gpus, timeout=GPU_WORKER_START_S)
            yield client


def check_gpus(solver: SolverConfig, scheduler: str | None, gpus: int) -> None:
    """Refuse ``--gpus`` without the GPUs (local clusters) or without a torch backend in the spec."""
    if not gpus:
        return
    if not scheduler:
        cuda_devices(gpus)
    if solver.backend in (None, "numba"):
        raise ConfigError(
            f"--gpus runs the torch solver backend, but the spec's is {solver.backend or 'numba'!r}: set "
            '[solver] backend = "torch" (or "auto") in the spec; the backend is part of its hash'
        )


def plan_build(
    spec: BuildSpec,
    store: str | Path,
    scheduler: str | None = None,
    workers: int = 2,
    on_plan: Callable[[BuildEstimate], None] | None = None,
    gpus: int = 0,
) -> tuple[Plan, dict[str, SubjectSetup], str]:
    """Plan and check a build of ``spec`` into ``store`` without writing anything.

    Returns the plan, the subjects' set-ups (:func:`validate_plan`) and the
    store's canonical location. ``on_plan`` is shown the estimate, its time
    calibrated (a few solver steps), before :func:`check_resources` refuses a
    build that does not fit the workers' memory or the free disk space.
    ``gpus`` is checked first (:func:`check_gpus`); a local build then has
    one worker per GPU.
    """
    check_gpus(spec.solver, scheduler, gpus)
    workers = gpus or workers
    plan = make_plan(spec)
    setups = validate_plan(plan)  # every error that can be found before writing
    store = store_location(store, for_workers=True)
    estimate = estimate_build(plan, setups, store, scheduler, workers, calibrate=on_plan is not None)
    if on_plan:
        on_plan(estimate)
    check_resources(estimate)
    return plan, setups, store


def store_state(store: str, spec: BuildSpec, force: bool = False) -> LayoutState:
    """What a build of ``spec`` does with ``store``, after every check of the store it runs before writing.

    Reads only. A store of ``spec`` is resumed when its structure is sound
    (:func:`~simgen.store.structure.refuse_damaged` refuses it otherwise), or
    replaced when damaged and ``force``; another spec or schema version is
    refused unless ``force`` (:func:`~simgen.store.layout.layout_state`).
    """
    state = layout_state(store, spec_hash(spec), force)
    if state == "resume" and force and structure_damage(store):
        return "replace"
    if state == "resume":
        refuse_damaged(store)
    return state


def dry_run(
    spec: BuildSpec,
    store: str | Path,
    scheduler: str | None = None,
    workers: int = 2,
    force: bool = False,
    on_plan: Callable[[BuildEstimate], None] | None = None,
    gpus: int = 0,
) -> LayoutState:
    """Every check :func:`build` runs before it writes, writing nothing: the plan (:func:`plan_build`), the
    store's lock (:func:`~simgen.store.lock.check_unlocked`) and the store (:func:`store_state`, returned)."""
    _, _, store = plan_build(spec, store, scheduler, workers, on_plan, gpus)
    check_unlocked(store)
    return store_state(store, spec, force)


def build(
    spec: BuildSpec,
    store: str | Path,
    scheduler: str | None = None,
    workers: int = 2,
    force: bool = False,
    retries: int = 2,
    on_start: Callable[[int, str | None], None] | None = None,
    on_done: Callable[[str], None] | None = None,
    on_plan: Callable[[BuildEstimate], None] | None = None,
    gpus: int = 0,
) -> BuildReport:
    """Build (or resume) the dataset of ``spec`` into ``store``.

    ``store`` is a folder (made absolute, so that workers started elsewhere
    write to the same one) or an fsspec URL such as ``s3://bucket/name.zarr``
    that every worker can reach (:mod:`simgen.store.location`).
    ``on_plan(estimate)`` (:func:`plan_build`), ``on_start(n_tasks,
    dashboard_link)`` and ``on_done(task_key)`` let a caller show the plan and
    progress. ``gpus``: run every task on a worker that owns a GPU
    (:func:`dask_client`), with the spec's torch backend. Raises
    :class:`BuildFailed` naming the tasks that failed ``retries + 1`` times;
    the store keeps every finished chunk.
    """
    start = time.perf_counter()
    plan, setups, store = plan_build(spec, store, scheduler, workers, on_plan, gpus)
    with StoreLock(store):
        if store_state(store, spec, force) == "replace":
            location.clear(store, keep={LOCK_NAME})  # the lock stays: this build holds the store
        create_layout(store, plan, spec_to_dict(spec), spec_hash(spec), setups=setups)
        report = run_pending(store, spec.solver, scheduler, workers, retries, on_start, on_done, gpus=gpus)
    report.seconds = time.perf_counter() - start
    return report


def subject_workers(tasks: list[Task], workers: list[str]) -> dict[str, list[str]]:
    """A preferred worker per subject, balancing pending chunks (largest subjects first).

    A worker builds a subject's simulator (operator, eigenvalue bound, mesh and
    tissue reads) once and keeps it, so keeping a subject's chunks on one
    worker saves the set-up on the others; the preference is loose, so idle
    workers still steal. Empty with fewer than two workers.
    """
    if len(workers) < 2:
        return {}
    chunks = Counter(t.subject_id for t in tasks)
    load = dict.fromkeys(workers, 0)
    home = {}
    for subject, n in sorted(chunks.items(), key=lambda kv: (-kv[1], kv[0])):
        worker = min(load, key=load.__getitem__)
        home[subject], load[worker] = [worker], load[worker] + n
    return home


def _run_round(
    client: Client,
    store: str,
    solver: SolverConfig,
    tasks: list[Task],
    retries: int,
    on_done: Callable[[str], None] | None,
    gpus: int = 0,
) -> tuple[dict[str, str], dict[str, str]]:
    """Run ``tasks`` on the cluster (with ``gpus``: on its GPU workers), then wait for every worker's last write.

    Returns what failed, by task key: the tasks that raised (after Dask's
    ``retries``), and the chunk writes that failed once their task had returned.
    """
    workers = gpu_workers(client) if gpus else list(client.scheduler_info()["workers"])
    home = subject_workers(tasks, workers)
    # Dask treats tasks of one key as one: the store in the key keeps builds of two stores that share a
    # cluster (and subject ids) from taking each other's chunks for their own.
    store_key = hashlib.sha256(store.encode()).hexdigest()[:8]
    futures = {
        client.submit(
            run_task,
            store,
            t.subject_id,
            t.chunk,
            t.start,
            t.stop,
            solver,
            key=f"simgen-{store_key}-{t.subject_id}-{t.chunk}",
            retries=retries,
            pure=False,
            workers=home.get(t.subject_id),
            allow_other_workers=t.subject_id in home,
            resources={"GPU": 1} if gpus else None,
        ): t
        for t in tasks
    }
    errors = {}
    for future in as_completed(futures):
        task = futures[future]
        if future.status == "error":
            errors[task.key] = repr(future.exception())
        elif on_done:
            on_done(task.key)
    write_errors = {key: why for failed in client.run(flush_writes).values() for key, why in failed}
    return errors, write_errors


def run_pending(
    store: str,
    solver: SolverConfig,
    scheduler: str | None = None,
    workers: int = 2,
    retries: int = 2,
    on_start: Callable[[int, str | None], None] | None = None,
    on_done: Callable[[str], None] | None = None,
    subjects: list[str] | None = None,
    gpus: int = 0,
) -> BuildReport:
    """Simulate every chunk of ``store`` (or of ``subjects``) not flagged done, then finish the store.

    The caller holds the store lock. Tasks come from the store layout itself,
    so builds, added subjects and regenerated chunks all run through here.
    Finishing sets the statistics of ``subjects`` (default: all) and of the
    store, the short card (root attribute ``summary``) and ``complete``, and
    consolidates the metadata; all follow from the store's contents, so a
    resumed build ends byte-identical to an uninterrupted one (of the same
    backend: torch on a GPU is not bitwise numba, docs/solver-backends.md).
    ``gpus``: as for :func:`dask_client`.
    """
    start = time.perf_counter()
    chunks = chunk_tasks(store, subjects)
    todo = [task for task, done in chunks.items() if not done]  # still pending; read again after each round
    report = BuildReport(store, len(chunks), len(todo), sum(t.stop - t.start for t in todo), 0.0)
    if todo:
        with dask_client(scheduler, workers, gpus) as client:
            report.dashboard = client.dashboard_link
            if on_start:
                on_start(len(todo), report.dashboard)
            errors, _ = _run_round(client, store, solver, todo, retries, on_done, gpus)
            # a chunk whose write failed after its task returned, or whose worker died first, is still pending
            todo = pending_tasks(store, subjects)
            redo = [t for t in todo if t.key not in errors]
            if redo:
                again, write_errors = _run_round(client, store, solver, redo, retries, None, gpus)
                todo = pending_tasks(store, subjects)
                left = {t.key for t in todo} - errors.keys() - again.keys()
                errors |= again | {key: write_errors.get(key, "simulated twice, never written") for key in left}
            report.failed = [f"{key}: {why}" for key, why in errors.items()]
    if report.failed:
        raise BuildFailed(
            f"{len(report.failed)} task(s) failed after {retries} retries; finished chunks are kept, "
            "rerun the build to retry them:\n  " + "\n  ".join(report.failed)
        )
    summary = {"statistics": write_statistics(store, subjects), "summary": short_card(store_facts(store))}
    consolidate(store, complete=not todo if subjects is None else None, attrs=summary)  # others may be pending
    report.seconds = time.perf_counter() - start
    return report
