"""Integrity check of a dataset store: structure, checksums, completeness, values, fingerprints, recomputation.

:func:`verify_store` first compares the store with the structure its
recorded spec implies (:mod:`simgen.store.structure`: every group, array and
attribute, each array's metadata and codecs, the checksums of the mesh,
tissue, coordinate and done-flag arrays, the coordinates against the mesh).
It then reads the result arrays one chunk at a time (never a whole array), so
a corrupted or truncated chunk file becomes a problem naming its subject,
array and chunk instead of a crash, and checks each done chunk's values, its
moments (schema version 2 on) and its fingerprint (version 3), and the
statistics against the moments. Finally ``sample`` done chunks of every
subject are simulated again in-process and compared bitwise with the stored
data: the solver is deterministic and independent of how sites are batched,
so any difference means the stored chunk is not what the spec produces.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr
from numpy.typing import NDArray

from shared.ecg import PseudoECG
from shared.integrity import read_failure
from shared.schema import METADATA_VERSION, SCHEMA_VERSION, mesh_path, subject_path
from shared.units import U_RANGE
from simgen.solver.backends import BACKEND_TOLERANCE
from simgen.solver.simulate import SimulationResult, Simulator, SolverConfig
from simgen.store.fingerprint import chunk_fingerprint
from simgen.store.layout import check_store, read_mesh, read_sites, read_tissue
from simgen.store.location import store_location
from simgen.store.metadata import recorded_solver
from simgen.store.stats import chunk_moments, statistics
from simgen.store.structure import (
    GROUP,
    GROUP_METADATA,
    METADATA,
    Damage,
    read_done,
    recorded_structure,
    structure_damage,
)
from simgen.store.worker import ecg_leads, subject_ecg

__all__ = ["U_RANGE", "ChunkRef", "VerifyReport", "chunk_problems", "verify_store"]


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
    """Outcome of :func:`verify_store`; the store is fine when ``problems`` is empty.

    ``damage``: the structural findings (also in ``problems``); ``damaged_chunks``:
    the done chunks whose data fail a check (unreadable, values, moments,
    fingerprint, recomputation), which ``simgen repair`` computes again.
    """

    store: str
    problems: list[str] = field(default_factory=list)
    chunks_checked: int = 0
    chunks_recomputed: int = 0
    damage: list[Damage] = field(default_factory=list)
    damaged_chunks: list[ChunkRef] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """``True`` when no problem was found."""
        return not self.problems

    def chunk_problems(self, ref: ChunkRef, problems: list[str]) -> None:
        """Record the problems of done chunk ``ref`` (nothing when ``problems`` is empty)."""
        if problems:
            self.problems.extend(problems)
            self.damaged_chunks.append(ref)


def _chunk_refs(subject_id: str, n_sites: int, chunk_sites: int) -> Iterator[ChunkRef]:
    for k, start in enumerate(range(0, n_sites, chunk_sites)):
        yield ChunkRef(subject_id, k, start, min(start + chunk_sites, n_sites))


def _read(arr: zarr.Array, ref: ChunkRef, name: str) -> tuple[NDArray | None, str | None]:
    """Chunk ``ref`` of ``arr``, or ``None`` and a problem naming the chunk file (and, in a shard of
    one inner chunk per site, the sites that do not decode) when it cannot be decoded."""
    try:
        return arr[ref.start : ref.stop], None
    except Exception as exc:  # codec / zarr errors of a corrupted or truncated chunk file
        key = arr.metadata.encode_chunk_key((ref.chunk,) + (0,) * (arr.ndim - 1))
        where = f"{subject_path(ref.subject_id)}/{name}/{key}"
        sites = f", sites {_unreadable_sites(arr, ref)}" if arr.chunks[0] == 1 < ref.stop - ref.start else ""
        return None, f"{ref}: {name} chunk unreadable (file {where}{sites}): {type(exc).__name__}: {exc}"


def _unreadable_sites(arr: zarr.Array, ref: ChunkRef) -> list[int]:
    """The sites of ``ref`` whose inner chunk of ``arr`` does not decode (each is read alone)."""
    bad = []
    for site in range(ref.start, ref.stop):
        try:
            arr[site]
        except Exception:  # this site's inner chunk (or the shard index) is damaged
            bad.append(site)
    return bad


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


def chunk_problems(g: zarr.Group, ref: ChunkRef, version: int) -> list[str]:
    """Everything wrong with done chunk ``ref``: unreadable data, values, moments, fingerprint."""
    u, err_u = _read(g["u"], ref, "u")
    activation, err_a = _read(g["activation"], ref, "activation")
    if err_u or err_a:
        return [e for e in (err_u, err_a) if e]
    problems = _value_problems(ref, u, activation)
    if "ecg" in g:
        ecg, err = _read(g["ecg"], ref, "ecg")
        if err or not np.all(np.isfinite(ecg)):
            problems.append(err or f"{ref}: ecg not written (NaN) or not finite")
    if problems or version < METADATA_VERSION:
        return problems
    for name in ("moments", "fingerprint")[: 1 + (version >= SCHEMA_VERSION)]:
        arr = g[name]
        try:
            stored = arr[ref.chunk]
        except Exception as exc:  # a corrupted or truncated file
            return [f"{ref}: {name} {read_failure(arr, (ref.chunk,) + (0,) * (arr.ndim - 1), exc)}"]
        if name == "moments" and not np.array_equal(stored, chunk_moments(u, activation)):
            return [f"{ref}: stored moments differ from the chunk's data"]
        if name == "fingerprint" and int(stored) != chunk_fingerprint(*_place(ref), u, activation):
            return [
                f"{ref}: content fingerprint differs: its data and moments were written for another "
                "subject or other sites (a chunk file moved or copied?)"
            ]
    return []


def _place(ref: ChunkRef) -> tuple[str, int, int, int]:
    return ref.subject_id, ref.chunk, ref.start, ref.stop


def _check_chunks(root: zarr.Group, subject_id: str, report: VerifyReport, version: int) -> list[ChunkRef]:
    """Check every chunk of one subject; return the done chunks that read back fine."""
    g = root[subject_path(subject_id)]
    done, unreadable = read_done(g["done"])
    good = []
    for ref in _chunk_refs(subject_id, g["u"].shape[0], int(g.attrs["chunk_sites"])):
        if ref.chunk in unreadable:
            continue  # named with the structure
        if not done[ref.chunk]:
            report.problems.append(f"{ref} not done")
            continue
        report.chunks_checked += 1
        problems = chunk_problems(g, ref, version)
        report.chunk_problems(ref, problems)
        if not problems:
            good.append(ref)
    return good


#: How far a stored ECG may be from the recomputed simulations' (relative to its largest lead value): the
#: rounding of the dense product on another machine, or (``False``: a store not built with numba) the
#: backends' differences in ``u``.
ECG_RTOL = {True: 1e-5, False: 1e-2}


def _recompute(store: str, root: zarr.Group, refs: list[ChunkRef], solver: SolverConfig, report: VerifyReport) -> None:
    """Simulate ``refs`` again with the numba backend and compare with the stored chunks.

    Bitwise for a store whose spec names no other backend; within
    :data:`~simgen.solver.backends.BACKEND_TOLERANCE` for one built with torch
    (or ``auto``, which may have used it), whose results are not numba's bit for bit.
    """
    sims: dict[str, tuple[Simulator, NDArray, PseudoECG | None]] = {}
    for ref in refs:
        g = root[subject_path(ref.subject_id)]
        if ref.subject_id not in sims:
            mesh_id = g.attrs["mesh_id"]
            mesh = read_mesh(store, mesh_id)
            recorded = recorded_solver(store, ref.subject_id, solver, mesh)
            sim = Simulator(mesh, read_tissue(store, ref.subject_id), recorded, backend="numba")
            ecg = subject_ecg(store, mesh_id, sim) if "ecg" in g else None
            sims = {ref.subject_id: (sim, read_sites(store, mesh_id), ecg)}  # keep one subject's operators
        sim, sites, ecg = sims[ref.subject_id]
        result = sim.run(sites[ref.start : ref.stop], threads=1)
        u, activation = g["u"][ref.start : ref.stop], g["activation"][ref.start : ref.stop]
        exact = solver.backend in (None, "numba")
        problems = _recomputed_differences(ref, u, activation, result, exact)
        if ecg is not None:
            expected = ecg_leads(ecg, result.u)
            stored, rtol = g["ecg"][ref.start : ref.stop], ECG_RTOL[exact]
            if not np.allclose(stored, expected, rtol=rtol, atol=rtol * np.abs(expected).max()):
                problems.append(f"{ref}: stored ecg differs from the recomputed simulations' pseudo-ECG")
        report.chunk_problems(ref, problems)
        report.chunks_recomputed += 1


def _recomputed_differences(
    ref: ChunkRef, u: NDArray, activation: NDArray, result: SimulationResult, exact: bool
) -> list[str]:
    """How stored ``u`` and ``activation`` differ from ``result``: at all (``exact``), else beyond the tolerance."""
    problems = []
    u_tol, steps = (0.0, 0.0) if exact else BACKEND_TOLERANCE
    diff = float(np.max(np.abs(u.astype(np.float64) - result.u)))
    if not diff <= u_tol:  # NaN too
        problems.append(f"{ref}: stored u differs from recomputation (max |diff| {diff:.3g}{_limit(u_tol)})")
    never = np.isnan(result.activation)
    late = np.abs(activation - result.activation)[~never].max(initial=0.0) / result.dt
    if not np.array_equal(np.isnan(activation), never) or late > steps:
        problems.append(f"{ref}: stored activation differs from recomputation{_limit(steps, ' time step(s)')}")
    return problems


def _limit(tolerance: float, unit: str = "") -> str:
    return f", more than the {tolerance:g}{unit} admitted between solver backends" if tolerance else ""


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


def _sample(candidates: list[ChunkRef], per_subject: int, seed: int) -> list[ChunkRef]:
    """Up to ``per_subject`` chunks of each subject, drawn by ``seed``; subject then chunk order."""
    rng = np.random.default_rng(seed)
    by_subject: dict[str, list[ChunkRef]] = {}
    for ref in candidates:
        by_subject.setdefault(ref.subject_id, []).append(ref)
    picked = []
    for refs in by_subject.values():
        n = min(per_subject, len(refs))
        picked += [refs[i] for i in sorted(rng.choice(len(refs), size=n, replace=False).tolist())]
    return picked


def verify_store(store: str | Path, sample: int = 1, seed: int = 0) -> VerifyReport:
    """Check the structure and every chunk of ``store``; recompute ``sample`` done chunks of every subject.

    Parameters
    ----------
    store : folder or fsspec URL (``s3://bucket/name.zarr``) of the dataset store.
    sample : done, readable chunks per subject simulated again and compared bitwise (0: none).
    seed : seed of the chunk sample (:func:`numpy.random.default_rng`).

    Returns
    -------
    VerifyReport
        Every problem found (missing, extra or corrupted pieces of the
        structure; unfinished, unreadable, non-finite, out-of-range, moved or
        differing chunks), each naming its mesh or subject and, for a chunk,
        its index and sites.

    Raises
    ------
    SchemaError
        When ``store`` is not a store of a schema version this code reads
        (older versions are checked without what was added since).
    """
    store = store_location(store)
    attrs = check_store(store)
    version, recorded = attrs["schema_version"], recorded_structure(attrs)
    root = zarr.open_group(store, mode="r", use_consolidated=False)  # what is stored, not a copy of its metadata
    report = VerifyReport(store, damage=structure_damage(store))
    report.problems.extend(map(str, report.damage))
    unopened = {d.group for d in report.damage if d.kind in (GROUP, GROUP_METADATA, METADATA)}  # not read further
    ids = [
        subject_id
        for subject_id, mesh_id in recorded.subjects.items()
        if not {subject_path(subject_id), mesh_path(mesh_id)} & unopened
    ]
    candidates = [ref for s in ids for ref in _check_chunks(root, s, report, version)]
    if version >= METADATA_VERSION and not report.problems:
        report.problems.extend(_statistics_problems(root, list(recorded.subjects)))
    damaged = {d.group for d in report.damage}  # a subject is recomputed on a sound mesh and tissue only
    sound = [
        ref
        for ref in candidates
        if not {subject_path(ref.subject_id), mesh_path(recorded.subjects[ref.subject_id])} & damaged
    ]
    _recompute(store, root, _sample(sound, max(int(sample), 0), seed), recorded.spec.solver, report)
    return report
