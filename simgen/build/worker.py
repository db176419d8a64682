"""What a Dask worker runs: simulate one chunk of sites of one subject and store it.

Everything a task needs is read from the store the driver laid out (mesh,
sites, tissue fields), so workers on other hosts need only the store path.
The assembled :class:`Simulator` and the opened result arrays of recent
subjects are kept per process (:func:`prepare`).
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import NamedTuple

import numpy as np
import zarr

from shared.schema import subject_path
from simgen.build.store import read_mesh, read_sites, read_tissue, result_arrays, write_chunk
from simgen.solver.simulate import Simulator, SolverConfig

__all__ = ["Prepared", "prepare", "run_task"]

_CACHE: OrderedDict[tuple, "Prepared"] = OrderedDict()
_CACHE_SIZE = 4


class Prepared(NamedTuple):
    """What a worker keeps per subject: the assembled simulator, the site list, the result arrays."""

    sim: Simulator
    sites: np.ndarray
    arrays: tuple[zarr.Array, zarr.Array, zarr.Array]


def prepare(store: str, subject_id: str, solver: SolverConfig) -> Prepared:
    """The subject's :class:`Prepared` state, built once per process and subject (last few kept)."""
    # the spec hash keeps a store rebuilt under the same path (--force) from reusing stale entries
    key = (store, zarr.open_group(store, mode="r").attrs["spec_hash"], subject_id, solver)
    if key not in _CACHE:
        mesh_id = zarr.open_group(store, path=subject_path(subject_id), mode="r").attrs["mesh_id"]
        sim = Simulator(read_mesh(store, mesh_id), read_tissue(store, subject_id), solver)
        _CACHE[key] = Prepared(sim, read_sites(store, mesh_id), result_arrays(store, subject_id))
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    _CACHE.move_to_end(key)
    return _CACHE[key]


def run_task(store: str | Path, subject_id: str, chunk: int, start: int, stop: int, solver: SolverConfig) -> str:
    """Simulate sites ``[start, stop)`` of ``subject_id`` single-threaded and write chunk ``chunk``."""
    sim, sites, arrays = prepare(str(store), subject_id, solver)
    result = sim.run(sites[start:stop], threads=1)
    write_chunk(store, subject_id, chunk, start, stop, result.u, result.activation, arrays)
    return f"{subject_id}/{chunk}"
