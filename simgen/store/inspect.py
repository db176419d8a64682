"""Read-only views of a store: per-subject progress and the damage a cheap check finds (``simgen status``).

:func:`store_health` runs the structural check of ``simgen verify``
(:func:`~simgen.store.structure.structure_damage`: every group, array and
attribute against the recorded spec, the small arrays' checksums) and the
readers' check of every done chunk (:class:`shared.integrity.SubjectReader`:
shard indices and content fingerprints, from the chunks' stored checksums;
no result data is decoded), so a deleted, truncated, moved or copied shard is
named as well as a missing group. It never raises for damage: whatever
cannot be read is a finding. A damaged inner chunk whose index and checksum
entry are intact is found only by decoding it: ``simgen verify``, or
``simgen status --checksums``, which runs verify's checks of every chunk.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import zarr

from shared.capture import started_wave
from shared.errors import InputError
from shared.integrity import SubjectReader
from shared.reader import implied_subject_ids
from shared.schema import subject_path
from simgen.store.layout import check_store
from simgen.store.location import store_location
from simgen.store.structure import (
    GROUP,
    GROUP_METADATA,
    METADATA,
    read_done,
    recorded_structure,
    stored_names,
    structure_damage,
)
from simgen.store.verify import verify_store

__all__ = ["SubjectStatus", "StoreHealth", "store_status", "store_health"]

#: Root attributes without which the recorded structure is unknown.
_ROOT = ("schema_version", "spec")


@dataclass(frozen=True)
class SubjectStatus:
    subject_id: str
    mesh_id: str
    chunks: int
    chunks_done: int
    sites: int
    damaged: int = 0  # done chunks that fail the readers' check
    missing: bool = False  # implied by the recorded spec, not in the store (or unreadable)
    no_wave: int | None = None  # sites whose stimulus starts no wave (None: not recorded, or chunks pending)


@dataclass
class StoreHealth:
    """Progress per subject and every problem found (``problems`` empty: nothing found)."""

    store: str
    rows: list[SubjectStatus] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    checksums: bool = False  # every done chunk was decoded (``simgen status --checksums``)


def _subject_row(
    store: str, root: zarr.Group, subject_id: str, version: int, health: StoreHealth, decoded: set[int]
) -> None:
    """The row of one subject; ``decoded``: its done chunks that failed ``simgen verify``'s decoding checks."""
    try:
        g = root[subject_path(subject_id)]
        mesh_id = str(g.attrs.get("mesh_id", "?"))
        flags, _ = read_done(g["done"])  # a damaged flag reads as not done (and is named by the structure check)
        reader = SubjectReader(store, subject_id, version, done=flags)
    except (KeyError, InputError):  # named by the structural check
        health.rows.append(SubjectStatus(subject_id, "?", 0, 0, 0, missing=True))
        return
    except Exception as exc:  # noqa: BLE001 - anything unreadable is a finding, never a traceback
        health.rows.append(SubjectStatus(subject_id, "?", 0, 0, 0, missing=True))
        health.problems.append(f"subject {subject_id}: unreadable ({type(exc).__name__}: {exc})")
        return
    done = reader.done == 1
    bad = set(decoded)
    for chunk in map(int, done.nonzero()[0]):
        try:
            reader.check_chunk(chunk)
        except InputError as exc:
            bad.add(chunk)
            health.problems.append(str(exc).split("; run `simgen repair")[0].removeprefix(f"store {store}: "))
        except Exception as exc:  # noqa: BLE001
            bad.add(chunk)
            health.problems.append(f"subject {subject_id}: chunk {chunk} unreadable ({type(exc).__name__}: {exc})")
    damaged = len(bad)
    sound = int(done.sum()) - damaged
    health.rows.append(
        SubjectStatus(subject_id, mesh_id, len(done), sound, reader.n_sites, damaged, no_wave=_no_wave(g.attrs))
    )


def _no_wave(attrs) -> int | None:
    """The number of sites whose stimulus started no wave, from the subject's ``capture`` attribute."""
    capture = attrs.get("capture")
    if not isinstance(capture, dict) or not isinstance(capture.get("activated_fraction"), list):
        return None
    return int((~started_wave(capture["activated_fraction"])).sum())


def store_health(store: str | Path, checksums: bool = False) -> StoreHealth:
    """Chunks done per subject and the damage of the structure and of the done chunks (see the module docstring).

    ``checksums``: also decode every done chunk as ``simgen verify`` does
    (every checksum, value, moment and fingerprint; no recomputation), so the
    health found is what verify finds. Raises :class:`~shared.errors.SchemaError`
    only for what is not a simgen store of a readable version.
    """
    store = store_location(store)
    attrs = check_store(store)
    health = StoreHealth(store)
    missing_root = [name for name in _ROOT if name not in attrs]
    if missing_root:
        health.problems.append(f"store: root attribute(s) {', '.join(missing_root)} missing")
        return health
    try:
        damage = structure_damage(store)
    except Exception as exc:  # noqa: BLE001 - a store too damaged to compare is a finding
        damage = []
        health.problems.append(f"store: structure cannot be checked ({type(exc).__name__}: {exc})")
    health.problems += [str(d) for d in damage]
    decoded: dict[str, set[int]] = {}
    if checksums and not damage:
        found = verify_store(store, sample=0)
        for ref in found.damaged_chunks:
            decoded.setdefault(ref.subject_id, set()).add(ref.chunk)
        health.checksums = True
        health.problems += [p for p in found.problems if p not in health.problems and not p.endswith(" not done")]
    broken = {d.group for d in damage if d.kind in (GROUP, GROUP_METADATA, METADATA)}
    root = zarr.open_group(store, mode="r", use_consolidated=False)
    version = int(attrs["schema_version"])
    stored = sorted(stored_names(root, "subjects"))
    ids = list(dict.fromkeys([*(implied_subject_ids(attrs) or []), *stored]))
    try:
        recorded = recorded_structure(attrs)
    except Exception:  # noqa: BLE001 - an unreadable spec: named by the structure check
        recorded = None
    for subject_id in sorted(ids):
        if subject_path(subject_id) in broken or subject_id not in stored:
            mesh_id, sites, chunks = "?", 0, 0
            if recorded is not None and subject_id in recorded.subjects:  # what the spec implies
                mesh_id = recorded.subjects[subject_id]
                sites = recorded.sites[mesh_id]
                chunks = -(-sites // recorded.spec.output.chunk_sites)
            health.rows.append(SubjectStatus(subject_id, mesh_id, chunks, 0, sites, missing=True))
            continue
        _subject_row(store, root, subject_id, version, health, decoded.get(subject_id, set()))
    return health


def store_status(store: str | Path) -> list[SubjectStatus]:
    """Chunks done per subject (works on unfinished and finished stores); :func:`store_health` names the damage."""
    return [row for row in store_health(store).rows if not row.missing]
