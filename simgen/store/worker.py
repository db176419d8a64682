"""What a Dask worker runs: simulate one chunk of sites of one subject and store it.

Everything a task needs is read from the store the driver laid out (mesh,
sites, tissue fields), so workers on other hosts need only the store path.
The assembled :class:`Simulator` and the opened result arrays of recent
subjects are kept per process (:func:`prepare`). In a build, a task hands its
chunk to the process's :class:`BackgroundWriter` and returns: the chunk goes
to disk while the next one simulates, and the driver calls
:func:`flush_writes` on every worker before it reads the ``done`` flags.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np
import zarr

from shared.ecg import ELECTRODES, Electrodes, PseudoECG, leads
from shared.integrity import read_checked
from shared.schema import mesh_path, subject_path
from simgen.solver.simulate import Simulator, SolverConfig
from simgen.store.layout import ResultArrays, read_mesh, read_sites, read_tissue, result_arrays, write_chunk
from simgen.store.metadata import recorded_solver

__all__ = ["Prepared", "prepare", "run_task", "BackgroundWriter", "flush_writes", "SUBJECTS_KEPT"]

_CACHE: OrderedDict[tuple, Prepared] = OrderedDict()
#: Subjects whose simulator and arrays a worker process keeps (the memory estimate counts them all).
SUBJECTS_KEPT = 4


class Prepared(NamedTuple):
    """What a worker keeps per subject: the assembled simulator, the site list, the result arrays and, in a
    store that keeps ECGs, the subject's pseudo-ECG operator."""

    sim: Simulator
    sites: np.ndarray
    arrays: ResultArrays
    ecg: PseudoECG | None = None


def prepare(store: str, subject_id: str, solver: SolverConfig) -> Prepared:
    """The subject's :class:`Prepared` state, built once per process and subject (last few kept)."""
    # the spec hash keeps a store rebuilt under the same path (--force) from reusing stale entries
    key = (store, zarr.open_group(store, mode="r").attrs["spec_hash"], subject_id, solver)
    if key not in _CACHE:
        mesh_id = zarr.open_group(store, path=subject_path(subject_id), mode="r").attrs["mesh_id"]
        mesh = read_mesh(store, mesh_id)
        sim = Simulator(mesh, read_tissue(store, subject_id), recorded_solver(store, subject_id, solver, mesh))
        arrays = result_arrays(store, subject_id)
        ecg = None if arrays.ecg is None else subject_ecg(store, mesh_id, sim)
        _CACHE[key] = Prepared(sim, read_sites(store, mesh_id), arrays, ecg)
        while len(_CACHE) > SUBJECTS_KEPT:
            _CACHE.popitem(last=False)
    _CACHE.move_to_end(key)
    return _CACHE[key]


class BackgroundWriter:
    """One chunk write at a time on a thread of its own, so that the next chunk simulates meanwhile.

    :meth:`submit` first waits for the write before it (at most two chunks in
    memory). A write that fails is recorded with its chunk (its ``done`` flag
    stays unset, so the chunk is still pending in the store) and reported by
    :meth:`flush`; it does not fail the task that happens to come next.
    """

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="simgen-writer")
        self._pending: tuple[str, Future] | None = None
        self._failed: list[tuple[str, str]] = []
        self._lock = threading.Lock()

    def submit(self, key: str, write, *args) -> None:
        """Run ``write(*args)`` (the write of chunk ``key``) once the previous write is done."""
        with self._lock:
            self._wait()
            self._pending = key, self._pool.submit(write, *args)

    def flush(self) -> list[tuple[str, str]]:
        """Wait for the write in flight; return (and forget) ``(key, error)`` of every failed write."""
        with self._lock:
            self._wait()
            failed, self._failed = self._failed, []
            return failed

    def _wait(self) -> None:
        if self._pending is not None:
            (key, future), self._pending = self._pending, None
            if future.exception() is not None:
                self._failed.append((key, repr(future.exception())))


_WRITER = BackgroundWriter()


def flush_writes() -> list[tuple[str, str]]:
    """Wait for this process's chunk write in flight; the writes that failed since the last flush."""
    return _WRITER.flush()


def run_task(store: str | Path, subject_id: str, chunk: int, start: int, stop: int, solver: SolverConfig) -> str:
    """Simulate sites ``[start, stop)`` of ``subject_id`` single-threaded and hand chunk ``chunk`` to the writer.

    The chunk is written by this process's :class:`BackgroundWriter`: the
    caller must :func:`flush_writes` before relying on it.
    """
    sim, sites, arrays, operator = prepare(str(store), subject_id, solver)
    result = sim.run(sites[start:stop], threads=1)
    ecg = None if operator is None else ecg_leads(operator, result.u)
    key = f"{subject_id}/{chunk}"
    args = (store, subject_id, chunk, start, stop, result.u, result.activation, arrays, ecg)
    _WRITER.submit(key, write_chunk, *args)
    return key


def subject_ecg(store: str, mesh_id: str, sim: Simulator) -> PseudoECG:
    """The pseudo-ECG operator of a subject of a store that keeps ECGs: the mesh's stored electrodes, the
    subject's tissue and anisotropy."""
    group = zarr.open_group(store, path=mesh_path(mesh_id), mode="r")
    positions = read_checked(group, "ecg_electrodes", store, f"mesh {mesh_id}")
    config = sim.config
    electrodes = Electrodes(ELECTRODES, positions)
    return PseudoECG.assemble(sim.mesh, electrodes, sim.tissue.D, config.anisotropy, config.sheet_anisotropy)


def ecg_leads(operator: PseudoECG, u: np.ndarray) -> np.ndarray:
    """The stored ``ecg`` of simulations ``u``: their 12 leads (S, 12, T) in mV, float32."""
    return leads(operator.potentials(u), operator.electrodes).astype(np.float32)
