"""What the learner needs to know about a dataset store, read once: subjects, meshes, frames, hierarchies."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np

from learner.graph.hierarchy import MeshHierarchy, hierarchy_for_mesh
from shared.errors import InputError, SchemaError
from shared.mesh import Mesh
from shared.reader import (
    check_store,
    checked_subject_ids,
    read_mesh,
    read_sites,
    read_split,
    read_times,
    read_u,
    subject_array,
    subject_attrs,
)

__all__ = ["StoreView"]


class StoreView:
    """Read-only summary of a store plus a per-mesh cache of graph hierarchies.

    Parameters
    ----------
    store : path of the Zarr store (schema-checked on construction).
    cache_dir : where hierarchies are cached as ``.npz`` (None: in memory only).
    """

    def __init__(self, store: str | Path, cache_dir: str | Path | None = None) -> None:
        self.store = str(store)
        self.attrs = check_store(store)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._hierarchies: dict[tuple, MeshHierarchy] = {}
        self._meshes: dict[str, Mesh] = {}

    def __repr__(self) -> str:
        return f"StoreView({self.store!r}, subjects={len(self.subjects)}, frames={self.frames})"

    @cached_property
    def subjects(self) -> list[str]:
        """Every subject id, sorted; a subject the store's spec implies but the store lacks is an error."""
        return checked_subject_ids(self.store, self.attrs)

    @cached_property
    def mesh_of(self) -> dict[str, str]:
        """Subject id -> mesh id."""
        return {sid: subject_attrs(self.store, sid)["mesh_id"] for sid in self.subjects}

    @cached_property
    def tissue_of(self) -> dict[str, str]:
        """Subject id -> name of its tissue setting."""
        return {sid: subject_attrs(self.store, sid)["tissue"]["name"] for sid in self.subjects}

    @cached_property
    def stored_split(self) -> dict[str, str]:
        """Subject id -> part of the store's canonical split (empty for a version-1 store)."""
        return read_split(self.store)

    @cached_property
    def frames(self) -> int:
        """Frames per simulation (the same for every subject of a store)."""
        counts = {subject_array(self.store, s, "u").shape[1] for s in self.subjects}
        if len(counts) != 1:
            raise SchemaError(f"{self.store}: subjects have different frame counts {sorted(counts)}")
        return counts.pop()

    @cached_property
    def times(self) -> np.ndarray:
        """Output times (model time units) of the frames."""
        return read_times(self.store, self.subjects[0])

    def frame_means(self, subjects: list[str]) -> np.ndarray:
        """Mean potential per frame over every site and node of ``subjects``: the predictor that ignores all inputs."""
        total, count = np.zeros(self.frames), 0
        for sid in subjects:
            u = read_u(self.store, sid)
            total += u.sum(axis=(0, 2), dtype=np.float64)
            count += u.shape[0] * u.shape[2]
        return total / max(count, 1)

    def check_subject(self, subject_id: str) -> None:
        """Refuse an unknown subject id with the known ones in the message."""
        if subject_id not in self.mesh_of:
            raise InputError(f"unknown subject {subject_id!r}; the store has {', '.join(self.subjects)}")

    def mesh(self, mesh_id: str) -> Mesh:
        """The stored mesh (cached)."""
        if mesh_id not in self._meshes:
            self._meshes[mesh_id] = read_mesh(self.store, mesh_id)
        return self._meshes[mesh_id]

    def sites(self, mesh_id: str) -> np.ndarray:
        """Stimulation node ids of the mesh's site rows."""
        return read_sites(self.store, mesh_id)

    def hierarchy(self, mesh_id: str, levels: int, coarsest: int, working_nodes: int | None = None) -> MeshHierarchy:
        """The mesh's graph hierarchy (computed once, cached in memory and in ``cache_dir``); with
        ``working_nodes``, that of its working graph (:func:`~learner.graph.hierarchy.hierarchy_for_mesh`)."""
        key = (mesh_id, levels, coarsest, working_nodes)
        if key not in self._hierarchies:
            mesh = self.mesh(mesh_id)
            self._hierarchies[key] = hierarchy_for_mesh(mesh, levels, coarsest, self.cache_dir, working_nodes)
        return self._hierarchies[key]
