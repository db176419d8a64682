"""Integrity check of a dataset store: layout, metadata, completeness, readability, values, recomputation.

:func:`verify_store` reads the store one chunk at a time (never a whole
array), so a corrupted or truncated chunk file becomes a problem naming its
subject, array and chunk instead of a crash. In a store of the current schema
version it also checks the metadata: every array's dimensions and CF
attributes, the coordinates against the mesh, the canonical split, each
chunk's moments against its data and the statistics against the moments. A
random sample of done chunks is then simulated again in-process and compared
bitwise with the stored data: the solver is deterministic and independent of
how sites are batched, so any difference means the stored chunk is not what
the spec produces.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr
from numpy.typing import NDArray

from shared.schema import SCHEMA_VERSION, SUBJECT_ARRAYS, array_attributes, mesh_path, subject_path
from shared.split import canonical_part
from shared.units import MS_PER_TIME_UNIT
from simgen.build.location import store_location
from simgen.build.spec import BuildSpec, spec_from_mapping
from simgen.build.stats import chunk_moments, statistics
from simgen.build.store import check_store, read_mesh, read_sites, read_tissue, subject_ids, subject_shapes
from simgen.solver.simulate import Simulator, SolverConfig

__all__ = ["U_RANGE", "ChunkRef", "VerifyReport", "verify_store"]

#: Admissible range of the dimensionless potential ``u`` (rest 0, peak ~1, with margin).
U_RANGE = (-0.5, 1.5)


@dataclass(frozen=True)
class ChunkRef:
    """One chunk of sites ``[start, stop)`` of one subject."""

    subject_id: str
    chunk: int
    start: int
    stop: int

    def __str__(self) -> str:
        return f"subject {self.subject_id} chunk {self.chunk} (sites {self.start}..{self.stop - 1})"


@dataclass
class VerifyReport:
    """Outcome of :func:`verify_store`; the store is fine when ``problems`` is empty."""

    store: str
    problems: list[str] = field(default_factory=list)
    chunks_checked: int = 0
    chunks_recomputed: int = 0

    @property
    def ok(self) -> bool:
        """``True`` when no problem was found."""
        return not self.problems


def _chunk_refs(subject_id: str, n_sites: int, chunk_sites: int) -> Iterator[ChunkRef]:
    for k, start in enumerate(range(0, n_sites, chunk_sites)):
        yield ChunkRef(subject_id, k, start, min(start + chunk_sites, n_sites))


def _layout_problems(root: zarr.Group, subject_id: str, spec: BuildSpec, version: int) -> list[str]:
    """Missing arrays, wrong shapes, dtypes, dimensions or (current version) attributes of one subject."""
    try:
        g = root[subject_path(subject_id)]
        m = root[mesh_path(g.attrs["mesh_id"])]
        shapes = subject_shapes(m["points"].shape[0], m["stim_nodes"].shape[0], spec.output, spec.solver)
        arrays = {name: g[name] for name in shapes if SUBJECT_ARRAYS[name].since <= version}
    except Exception as exc:  # missing group, array or attribute
        return [f"subject {subject_id}: layout unreadable ({type(exc).__name__}: {exc})"]
    problems = []
    for name, arr in arrays.items():
        schema, shape = SUBJECT_ARRAYS[name], shapes[name][0]
        found = {"shape": tuple(arr.shape), "dtype": str(arr.dtype), "dimensions": arr.metadata.dimension_names}
        expected = {"shape": shape, "dtype": schema.dtype, "dimensions": schema.dims}
        if version == SCHEMA_VERSION:
            found["attributes"] = {k: arr.attrs.get(k) for k in ("units", "long_name", "coordinates")}
            expected["attributes"] = {"coordinates": None, **array_attributes(SUBJECT_ARRAYS, name)}
        problems += [
            f"subject {subject_id}: {name} has {key} {found[key]}, schema expects {expected[key]}"
            for key in expected
            if found[key] != expected[key]
        ]
    if version == SCHEMA_VERSION and not problems:
        problems += _metadata_problems(g, m, subject_id)
    return problems


def _metadata_problems(g: zarr.Group, m: zarr.Group, subject_id: str) -> list[str]:
    """Coordinates that disagree with the mesh, a wrong canonical split part, missing solver settings."""
    points = m["points"][...]
    expected = {
        "site": m["stim_nodes"][...],
        "time_ms": g["times"][...] * MS_PER_TIME_UNIT,
        **{axis: points[:, i] for i, axis in enumerate("xyz")},
    }
    problems = [
        f"subject {subject_id}: coordinate {name} disagrees with the mesh and times"
        for name, values in expected.items()
        if not np.array_equal(g[name][...], values)
    ]
    if g.attrs.get("split") != canonical_part(subject_id):
        problems.append(
            f"subject {subject_id}: split attribute {g.attrs.get('split')!r}, the canonical split "
            f"assigns {canonical_part(subject_id)!r}"
        )
    if not {"dt", "steps_per_frame", "stimulus_radius"} <= set(g.attrs.get("solver") or {}):
        problems.append(f"subject {subject_id}: solver attribute missing or incomplete")
    return problems


def _read(arr: zarr.Array, ref: ChunkRef, name: str) -> tuple[NDArray | None, str | None]:
    """Chunk ``ref`` of ``arr``, or ``None`` and a problem naming the chunk when it cannot be decoded."""
    try:
        return arr[ref.start : ref.stop], None
    except Exception as exc:  # codec / zarr errors of a corrupted or truncated chunk file
        key = arr.metadata.encode_chunk_key((ref.chunk,) + (0,) * (arr.ndim - 1))
        where = f"{subject_path(ref.subject_id)}/{name}/{key}"
        return None, f"{ref}: {name} chunk unreadable (file {where}): {type(exc).__name__}: {exc}"


def _value_problems(ref: ChunkRef, u: NDArray, activation: NDArray) -> list[str]:
    """Unwritten (NaN) or out-of-range ``u``, infinite activation times."""
    problems = []
    bad = ~np.isfinite(u)
    if bad.any():
        sites = sorted({ref.start + int(i) for i in np.flatnonzero(bad.any(axis=(1, 2)))})
        problems.append(f"{ref}: u has {int(bad.sum())} non-finite values (never written?) at sites {sites}")
    lo, hi = U_RANGE
    with np.errstate(invalid="ignore"):
        outside = int(((u < lo) | (u > hi)).sum())
    if outside:
        problems.append(
            f"{ref}: u has {outside} values outside [{lo}, {hi}] (min {np.nanmin(u):.3g}, max {np.nanmax(u):.3g})"
        )
    if np.isinf(activation).any():
        problems.append(f"{ref}: activation has {int(np.isinf(activation).sum())} infinite values")
    return problems


def _check_chunks(root: zarr.Group, subject_id: str, report: VerifyReport, version: int) -> list[ChunkRef]:
    """Check every chunk of one subject; return the done chunks that read back fine."""
    g = root[subject_path(subject_id)]
    try:
        done = np.asarray(g["done"][...]).astype(bool)
        moments = g["moments"][...] if version == SCHEMA_VERSION else None
    except Exception as exc:
        report.problems.append(f"subject {subject_id}: done flags or moments unreadable ({type(exc).__name__}: {exc})")
        return []
    good = []
    for ref in _chunk_refs(subject_id, g["u"].shape[0], int(g.attrs["chunk_sites"])):
        if not done[ref.chunk]:
            report.problems.append(f"{ref} not done")
            continue
        report.chunks_checked += 1
        u, err_u = _read(g["u"], ref, "u")
        activation, err_a = _read(g["activation"], ref, "activation")
        errors = [e for e in (err_u, err_a) if e]
        if not errors:
            errors = _value_problems(ref, u, activation)
        if not errors and moments is not None and not np.array_equal(moments[ref.chunk], chunk_moments(u, activation)):
            errors = [f"{ref}: stored moments differ from the chunk's data"]
        report.problems.extend(errors)
        if not errors:
            good.append(ref)
    return good


def _recompute(store: str, root: zarr.Group, refs: list[ChunkRef], solver: SolverConfig) -> list[str]:
    """Simulate ``refs`` again and compare bitwise with the stored chunks."""
    problems = []
    sims: dict[str, tuple[Simulator, NDArray]] = {}
    for ref in refs:
        if ref.subject_id not in sims:
            mesh_id = root[subject_path(ref.subject_id)].attrs["mesh_id"]
            sim = Simulator(read_mesh(store, mesh_id), read_tissue(store, ref.subject_id), solver)
            sims = {ref.subject_id: (sim, read_sites(store, mesh_id))}  # keep one subject's operator
        sim, sites = sims[ref.subject_id]
        result = sim.run(sites[ref.start : ref.stop], threads=1)
        g = root[subject_path(ref.subject_id)]
        u = g["u"][ref.start : ref.stop]
        if not np.array_equal(u, result.u):
            diff = float(np.max(np.abs(u.astype(np.float64) - result.u)))
            problems.append(f"{ref}: stored u differs from recomputation (max |diff| {diff:.3g})")
        if not np.array_equal(g["activation"][ref.start : ref.stop], result.activation, equal_nan=True):
            problems.append(f"{ref}: stored activation differs from recomputation")
    return problems


def _statistics_problems(root: zarr.Group, ids: list[str]) -> list[str]:
    """Statistics attributes that are not what the moments of finished subjects give."""
    problems, moments = [], []
    for subject_id in ids:
        g = root[subject_path(subject_id)]
        if not g["done"][...].all():
            continue
        moments.append(g["moments"][...])
        if g.attrs.get("statistics") != statistics(moments[-1]):
            problems.append(f"subject {subject_id}: statistics attribute differs from its chunk moments")
    if len(moments) == len(ids) and root.attrs.get("statistics") != statistics(np.concatenate(moments)):
        problems.append("store: statistics attribute differs from the subjects' chunk moments")
    return problems


def verify_store(store: str | Path, sample: int = 2, seed: int = 0) -> VerifyReport:
    """Check every chunk of ``store`` and recompute ``sample`` random done chunks.

    Parameters
    ----------
    store : folder or fsspec URL (``s3://bucket/name.zarr``) of the dataset store.
    sample : number of done, readable chunks simulated again and compared bitwise.
    seed : seed of the chunk sample (:func:`numpy.random.default_rng`).

    Returns
    -------
    VerifyReport
        Every problem found (unfinished, unreadable, mis-shaped, non-finite,
        out-of-range or differing chunks), each naming its subject and chunk.

    Raises
    ------
    SchemaError
        When ``store`` is not a store of a schema version this code reads
        (a version-1 store is checked without the metadata of version 2).
    """
    store = store_location(store)
    attrs = check_store(store)
    version, spec = attrs["schema_version"], spec_from_mapping(attrs["spec"])
    solver = spec.solver
    root = zarr.open_group(store, mode="r", use_consolidated=False)  # what is stored, not a copy of its metadata
    report = VerifyReport(store)
    candidates: list[ChunkRef] = []
    ids = subject_ids(store)
    for subject_id in ids:
        layout = _layout_problems(root, subject_id, spec, version)
        report.problems.extend(layout)
        if not layout:
            candidates.extend(_check_chunks(root, subject_id, report, version))
    if version == SCHEMA_VERSION and not report.problems:
        report.problems.extend(_statistics_problems(root, ids))
    n = min(max(int(sample), 0), len(candidates))
    picked = sorted(np.random.default_rng(seed).choice(len(candidates), size=n, replace=False).tolist())
    report.problems.extend(_recompute(store, root, [candidates[i] for i in picked], solver))
    report.chunks_recomputed = n
    return report
