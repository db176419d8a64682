"""One simulation per item: a map-style dataset over a store, for any model (operator networks, GNNs).

:class:`SimulationDataset` needs only numpy and zarr; it has ``len`` and
``[i]``, so ``torch.utils.data.DataLoader`` takes it as it is. Items are
dicts of numpy arrays. Meshes of different sizes give items with different
node counts: :func:`collate_graphs` joins them into one graph (PyG style),
:func:`collate_padded` pads them to a common size with a mask; both return
torch tensors.

The dataset holds the store location and small metadata only, so it pickles
to DataLoader workers; each process opens the store itself and caches the
per-subject tissue fields and the per-mesh points and edges it reads.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from shared.errors import InputError, SchemaError
from shared.mesh import Mesh
from shared.reader import (
    SubjectReader,
    check_store,
    checked_subject_ids,
    done_flags,
    read_mesh,
    read_sites,
    read_split,
    read_statistics,
    read_times,
    read_tissue,
    subject_array,
    subject_attrs,
)
from shared.split import SPLIT_FRACTIONS

__all__ = ["NODE_AXES", "SimulationDataset", "subset_statistics", "collate_graphs", "collate_padded"]

#: Node axis of each per-node array of an item; the collates join or pad along it.
NODE_AXES: dict[str, int] = {"u": 1, "activation": 0, "a": 0, "D": 0, "label": 0, "points": 0}

Item = dict[str, Any]


class SimulationDataset:
    """Every finished simulation of a store, or of some of its subjects, one per item.

    Parameters
    ----------
    store : str or Path
        The store: a folder or an fsspec URL (schema-checked).
    split : {"train", "validation", "test"}, optional
        Only the subjects of this part of the store's canonical split.
    subjects : sequence of str, optional
        Only these subjects (default: every subject, or those of ``split``).
    normalize : bool
        Standardise ``u`` and ``activation``: ``(x - mean) / std``.
    statistics : mapping, optional
        ``{"u": {"mean", "std", ...}, "activation": {...}}`` for ``normalize``;
        default the store's (root attribute ``statistics``, over every
        subject). :func:`subset_statistics` gives those of some subjects only,
        e.g. the training split's.
    edges : bool
        Add the mesh's undirected edges to each item (``"edges"``).
    transform : callable, optional
        Applied to each item before it is returned (e.g. to add features).

    Notes
    -----
    An item is a dict, ``T`` frames, ``N`` nodes of the subject's mesh:

    - ``u`` (T, N) float32: potential, dimensionless (``V = 100 u - 80`` mV);
    - ``activation`` (N,) float32: activation time in model time units
      (12.9 ms), NaN where the node never activates;
    - ``times``, ``time_ms`` (T,) float32: frame times in model units and in ms;
    - ``a``, ``D`` (N,) float32: excitability and diffusivity scale;
      ``label`` (N,) int8: 0 healthy, 1 border zone, 2 scar core;
    - ``points`` (N, 3) float32: node positions in mm;
    - ``edges`` (E, 2) int64 with ``edges=True``: undirected mesh edges;
    - ``site`` (int): the stimulated node; ``site_index`` (int): its row in the store;
    - ``subject``, ``mesh`` (str): subject id and mesh (anatomy) id.

    Simulations in a chunk whose ``done`` flag is 0 (an unfinished build) are
    left out. Each chunk an item reads is verified first
    (:class:`shared.integrity.SubjectReader`: checksums, content fingerprint,
    finite ``u``). The mesh's cells and node sets: :meth:`mesh`.

    Raises
    ------
    SchemaError
        Not a store of a readable version; ``normalize`` without statistics.
    DamagedData
        A subject the store's spec implies is missing; an item's chunk is
        damaged or misplaced (named with its subject, array, site and file).
    InputError
        Unknown split or subjects, both ``split`` and ``subjects``, no simulation left.
    """

    def __init__(
        self,
        store: str | Path,
        split: str | None = None,
        subjects: Sequence[str] | None = None,
        normalize: bool = False,
        statistics: Mapping[str, Mapping[str, float]] | None = None,
        edges: bool = False,
        transform: Callable[[Item], Item] | None = None,
    ) -> None:
        self.store = str(store)
        self.version = int(check_store(self.store)["schema_version"])
        self.subjects = _select_subjects(self.store, split, subjects)
        self.mesh_of = {sid: subject_attrs(self.store, sid)["mesh_id"] for sid in self.subjects}
        self.sites = {mesh_id: read_sites(self.store, mesh_id) for mesh_id in set(self.mesh_of.values())}
        self.statistics = _checked_statistics(self.store, statistics) if normalize else None
        self.with_edges, self.transform = edges, transform
        items = [(i, r) for i, sid in enumerate(self.subjects) for r in _done_rows(self.store, sid)]
        if not items:
            raise InputError(f"no finished simulation of the chosen subjects in {self.store}: finish the build")
        self._subject, self._row = np.asarray(items, np.int64).T
        self._cache: dict[tuple[str, str], Any] = {}

    def __len__(self) -> int:
        return len(self._row)

    def __getitem__(self, i: int) -> Item:
        if not -len(self) <= i < len(self):
            raise IndexError(f"item {i} outside a dataset of {len(self)} simulations")
        sid, row = self.subjects[self._subject[i]], int(self._row[i])
        mesh_id = self.mesh_of[sid]
        per_subject = self._cached("subject", sid, lambda: _subject_arrays(self.store, sid))
        per_mesh = self._cached("mesh", mesh_id, lambda: _mesh_arrays(self.mesh(mesh_id), self.with_edges))
        item = {
            "u": self._read("u", sid, row),
            "activation": self._read("activation", sid, row),
            **{key: value.copy() for key, value in {**per_subject, **per_mesh}.items()},  # a transform may edit them
            "site": int(self.sites[mesh_id][row]),
            "site_index": row,
            "subject": sid,
            "mesh": mesh_id,
        }
        return self.transform(item) if self.transform is not None else item

    def _read(self, name: str, subject_id: str, row: int) -> NDArray[np.float32]:
        """One site row of ``u`` or ``activation``, standardised with ``normalize``."""
        reader = self._cached("reader", subject_id, lambda: SubjectReader(self.store, subject_id, self.version))
        x = reader.rows(name, [row])[0]  # checked: done, checksums, content fingerprint, finite u
        if self.statistics is None:
            return x
        stats = self.statistics[name]
        return ((x - stats["mean"]) / stats["std"]).astype(np.float32)

    def __repr__(self) -> str:
        return (
            f"SimulationDataset({self.store!r}, subjects={len(self.subjects)}, simulations={len(self)}, "
            f"normalize={self.statistics is not None})"
        )

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_cache": {}}  # array handles stay in the process that opened them

    def mesh(self, mesh_id: str) -> Mesh:
        """The stored mesh: points, cells, node sets, long axis (read once per process)."""
        return self._cached("mesh object", mesh_id, lambda: read_mesh(self.store, mesh_id))

    def _cached(self, kind: str, key: str, read: Callable[[], Any]) -> Any:
        if (kind, key) not in self._cache:
            self._cache[kind, key] = read()
        return self._cache[kind, key]


def _select_subjects(store: str, split: str | None, subjects: Sequence[str] | None) -> list[str]:
    known = checked_subject_ids(store)
    if split is not None and subjects is not None:
        raise InputError("give a split or subjects, not both")
    if split is not None:
        if split not in SPLIT_FRACTIONS:
            raise InputError(f"unknown split {split!r}; choose one of {', '.join(SPLIT_FRACTIONS)}")
        parts = read_split(store)
        if not parts:
            raise SchemaError(f"{store} records no split (a version-1 store): pass subjects instead")
        chosen = [sid for sid in known if parts.get(sid) == split]
    elif subjects is not None:
        if isinstance(subjects, str):
            raise InputError(f"subjects must be a list of subject ids, not the string {subjects!r}")
        unknown = sorted(set(subjects) - set(known))
        if unknown:
            raise InputError(f"unknown subject(s) {', '.join(unknown)}; the store has {', '.join(known)}")
        chosen = list(dict.fromkeys(subjects))
    else:
        chosen = known
    if not chosen:
        raise InputError(f"no subject of {store} in split {split!r}" if split else f"{store} has no subjects")
    return chosen


def _done_rows(store: str, subject_id: str) -> NDArray[np.int64]:
    """Site rows of the subject whose chunk is done."""
    n_sites = subject_array(store, subject_id, "u").shape[0]
    chunk_sites = int(subject_attrs(store, subject_id)["chunk_sites"])
    rows = np.arange(n_sites)
    return rows[done_flags(store, subject_id)[rows // chunk_sites]]


def _checked_statistics(store: str, statistics: Mapping | None) -> Mapping:
    statistics = read_statistics(store) if statistics is None else statistics
    if statistics is None:
        raise SchemaError(
            f"{store} has no normalisation statistics (a version-1 store, or chunks pending): "
            "finish the build, or pass statistics"
        )
    for name in ("u", "activation"):
        stats = statistics.get(name) or {}
        if not (stats.get("mean") is not None and stats.get("std")):
            raise InputError(f"statistics of {name!r} need a mean and a non-zero std, got {stats!r}")
    return statistics


def _subject_arrays(store: str, subject_id: str) -> Item:
    """The per-subject arrays of an item: frame times and tissue fields."""
    tissue = read_tissue(store, subject_id)
    return {
        "times": read_times(store, subject_id).astype(np.float32),
        "time_ms": read_times(store, subject_id, "ms").astype(np.float32),
        "a": tissue.a.astype(np.float32),
        "D": tissue.D.astype(np.float32),
        "label": tissue.label.astype(np.int8),
    }


def _mesh_arrays(mesh: Mesh, edges: bool) -> Item:
    """The per-mesh arrays of an item: node positions and, with ``edges``, the undirected edges."""
    arrays = {"points": mesh.points.astype(np.float32)}
    if edges:
        arrays["edges"] = mesh.edges().astype(np.int64)
    return arrays


def subset_statistics(store: str | Path, subjects: Sequence[str]) -> dict[str, dict[str, float]]:
    """Normalisation statistics of ``u`` and ``activation`` over ``subjects`` only, from theirs.

    Counts, means and standard deviations combine exactly (population
    variance); the result has the form of :func:`shared.reader.read_statistics`.

    Raises
    ------
    SchemaError
        A subject has no statistics (version-1 store, or chunks pending).
    """
    per_subject = [read_statistics(store, sid) for sid in subjects]
    missing = [sid for sid, stats in zip(subjects, per_subject) if stats is None]
    if missing or not per_subject:
        raise SchemaError(f"no statistics for subject(s) {', '.join(missing) or '(none given)'} in {store}")
    combined = {}
    for name in per_subject[0]:
        parts = [stats[name] for stats in per_subject if stats[name]["count"]]
        count = sum(p["count"] for p in parts)
        mean = math.fsum(p["count"] * p["mean"] for p in parts) / count
        second = math.fsum(p["count"] * (p["std"] ** 2 + p["mean"] ** 2) for p in parts) / count
        combined[name] = {
            "count": count,
            "mean": mean,
            "std": math.sqrt(max(second - mean * mean, 0.0)),
            "min": min(p["min"] for p in parts),
            "max": max(p["max"] for p in parts),
        }
    return combined


def collate_graphs(items: Sequence[Item], node_axes: Mapping[str, int] = NODE_AXES) -> dict[str, Any]:
    """Join items into one graph of every item's nodes (PyG-style batching), as torch tensors.

    Per-node arrays (``node_axes``) are concatenated along their node axis,
    ``edges`` are shifted by each item's first node; ``batch`` (nodes,) gives
    the item of every node and ``ptr`` (items + 1,) the first node of each.
    Other arrays (``times``) are stacked, numbers become tensors and strings lists.
    """
    import torch

    sizes = [_node_count(item, node_axes) for item in items]
    ptr = np.concatenate([[0], np.cumsum(sizes)])
    out = _collate_rest(items, node_axes)
    for key in _node_keys(items, node_axes):
        out[key] = torch.cat([torch.as_tensor(item[key]) for item in items], dim=node_axes[key])
    if "edges" in items[0]:
        out["edges"] = torch.cat([torch.as_tensor(item["edges"]) + int(p) for item, p in zip(items, ptr)])
    out["batch"] = torch.repeat_interleave(torch.arange(len(items)), torch.as_tensor(sizes))
    out["ptr"] = torch.as_tensor(ptr)
    return out


def collate_padded(items: Sequence[Item], node_axes: Mapping[str, int] = NODE_AXES) -> dict[str, Any]:
    """Stack items with every per-node array zero-padded to the largest node count, as torch tensors.

    ``mask`` (items, nodes) marks the real nodes; ``edges`` stay a list of
    ``(E, 2)`` tensors. Other arrays are stacked, numbers become tensors and strings lists.
    """
    import torch

    sizes = [_node_count(item, node_axes) for item in items]
    width = max(sizes)
    out = _collate_rest(items, node_axes)
    for key in _node_keys(items, node_axes):
        padded = []
        for item, n in zip(items, sizes):
            x = np.asarray(item[key])
            pad = [(0, 0)] * x.ndim
            pad[node_axes[key]] = (0, width - n)
            padded.append(torch.as_tensor(np.pad(x, pad)))
        out[key] = torch.stack(padded)
    if "edges" in items[0]:
        out["edges"] = [torch.as_tensor(item["edges"]) for item in items]
    out["mask"] = torch.arange(width)[None, :] < torch.as_tensor(sizes)[:, None]
    return out


def _node_keys(items: Sequence[Item], node_axes: Mapping[str, int]) -> list[str]:
    return [key for key in items[0] if key in node_axes]


def _node_count(item: Item, node_axes: Mapping[str, int]) -> int:
    """Nodes of an item: the length of its first per-node array along the node axis."""
    for key, axis in node_axes.items():
        if key in item:
            return int(np.shape(item[key])[axis])
    raise InputError(f"an item needs one per-node array ({', '.join(node_axes)}) to count its nodes")


def _collate_rest(items: Sequence[Item], node_axes: Mapping[str, int]) -> dict[str, Any]:
    """Everything but per-node arrays and edges: strings to lists, numbers and other arrays to stacked tensors."""
    import torch

    out: dict[str, Any] = {}
    for key, value in items[0].items():
        if key in node_axes or key == "edges":
            continue
        values = [item[key] for item in items]
        if isinstance(value, str):
            out[key] = values
        elif isinstance(value, np.ndarray | torch.Tensor):
            out[key] = torch.stack([torch.as_tensor(v) for v in values])
        else:
            out[key] = torch.as_tensor(values)
    return out
