"""Read-only views of a store: per-subject progress."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import zarr

from simgen.build.location import store_location
from simgen.build.store import check_store

__all__ = ["SubjectStatus", "store_status"]


@dataclass(frozen=True)
class SubjectStatus:
    subject_id: str
    mesh_id: str
    chunks: int
    chunks_done: int
    sites: int


def store_status(store: str | Path) -> list[SubjectStatus]:
    """Chunks done per subject (works on unfinished and finished stores)."""
    store = store_location(store)
    check_store(store)
    root = zarr.open_group(store, mode="r")
    rows = []
    for subject_id, g in sorted(root["subjects"].groups()):
        done = g["done"][...]
        rows.append(SubjectStatus(subject_id, g.attrs["mesh_id"], len(done), int(done.sum()), g["u"].shape[0]))
    return rows
