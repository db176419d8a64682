"""Subject-level train / validation / test split.

Splitting is by subject, never by simulation: every simulation of a subject
lands in the same part, so a test subject's tissue is never seen in training.
Subjects on a held-out mesh all go to ``test`` (an unseen geometry, the
paper's real-data setting), those on a training mesh all to ``train`` (real
anatomies that must be trained on, whatever the shuffle); the others are
shuffled by ``seed`` and cut by fractions (``source = "computed"``, the
default) or take the part the store records for them (``source = "store"``:
the canonical split of :mod:`shared.split`, which subjects added later never
change). With ``by = "mesh"`` the computed cut is over meshes (anatomies)
instead of subjects: every subject of an anatomy lands in the same part, so
validation and test anatomies are never seen in training, whatever their
tissue. With ``by = "mesh+tissue"`` the meshes and the tissue settings are
cut apart, by the same fractions: a subject lands in a part when its mesh and
its tissue both do (its tissue counts as every part's when it is one of
``train_tissues``, settings every anatomy is trained on); the subjects of a
training mesh under a held-out tissue, or the other way round, are left out,
so test subjects pair an unseen anatomy with an unseen tissue draw.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from shared.errors import InputError

__all__ = ["SPLITS", "SplitSpec", "split_subjects"]

#: Names of the parts, in the order they are cut.
SPLITS = ("train", "validation", "test")


@dataclass(frozen=True)
class SplitSpec:
    """How to split subjects.

    Parameters
    ----------
    seed
        Seed of the shuffle (non-negative).
    validation, test
        Fractions of the subjects *not* on a held-out mesh; each in ``[0, 1)``,
        sum ``< 1``.
    held_out_meshes
        Mesh ids whose subjects all go to ``test``.
    train_meshes
        Mesh ids whose subjects all go to ``train``; they take no part in the
        shuffle and the cut, so adding them leaves validation and test as
        they were.
    source
        ``"computed"``: shuffle and cut as above; ``"store"``: the split
        recorded in the store (``seed`` and the fractions are then unused).
    by
        What the computed cut shuffles: ``"subject"``, ``"mesh"`` (whole
        anatomies; the fractions are then fractions of the meshes) or
        ``"mesh+tissue"`` (meshes and tissue settings each; module docstring).
    train_tissues
        With ``by = "mesh+tissue"``: tissue settings that take no part in the
        tissue cut, so that every part has them (e.g. named settings beside
        a spec's drawn ones).
    train_count
        ``0``: train on the whole training part; ``n > 0``: on only ``n`` of
        its units (meshes with ``by = "mesh"``, subjects otherwise), the first
        ``n`` of a shuffle by ``seed``, so the units of a smaller count are
        among those of a larger one. Validation and test do not change.
    """

    seed: int = 0
    validation: float = 0.1
    test: float = 0.2
    held_out_meshes: tuple[str, ...] = ()
    train_meshes: tuple[str, ...] = ()
    source: Literal["computed", "store"] = "computed"
    by: Literal["subject", "mesh", "mesh+tissue"] = "subject"
    train_count: int = 0
    train_tissues: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        # TOML gives lists; a tuple keeps the spec hashable and comparable.
        for name in ("held_out_meshes", "train_meshes", "train_tissues"):
            value = getattr(self, name)
            if isinstance(value, str):
                what = "tissue setting names" if name == "train_tissues" else "mesh ids"
                raise InputError(f"{name} must be a list of {what}, not the string {value!r}")
            object.__setattr__(self, name, tuple(value))
        both = sorted(set(self.held_out_meshes) & set(self.train_meshes))
        if both:
            raise InputError(f"mesh(es) {', '.join(both)} are both held out and training meshes")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise InputError(f"split seed must be a non-negative integer, got {self.seed!r}")
        for name in ("validation", "test"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value < 1.0):
                raise InputError(f"{name} fraction must be in [0, 1), got {value!r}")
        if self.source not in ("computed", "store"):
            raise InputError(f"split source must be 'computed' or 'store', got {self.source!r}")
        if self.by not in ("subject", "mesh", "mesh+tissue"):
            raise InputError(f"split by must be 'subject', 'mesh' or 'mesh+tissue', got {self.by!r}")
        if self.train_tissues and self.by != "mesh+tissue":
            raise InputError("split train_tissues keeps tissues out of the tissue cut: set by = 'mesh+tissue'")
        if isinstance(self.train_count, bool) or not isinstance(self.train_count, (int, np.integer)):
            raise InputError(f"train_count must be an integer (0 = all), got {self.train_count!r}")
        if self.train_count < 0:
            raise InputError(f"train_count must be >= 0 (0 = all), got {self.train_count}")
        if self.by != "subject" and self.source == "store":
            raise InputError(
                f"split by = {self.by!r} cuts anatomies, but the store's split is per subject; use source = 'computed'"
            )
        if self.validation + self.test >= 1.0:
            raise InputError(
                f"validation + test fractions must be < 1 to leave training subjects, "
                f"got {self.validation} + {self.test}"
            )


def _round_half_up(x: float) -> int:
    # Python's round() is banker's rounding (round(2.5) == 2); counts should not depend on parity.
    return int(np.floor(x + 0.5))


def split_subjects(
    subject_ids: Iterable[str],
    mesh_of: Mapping[str, str],
    spec: SplitSpec = SplitSpec(),
    stored: Mapping[str, str] | None = None,
    tissue_of: Mapping[str, str] | None = None,
) -> dict[str, list[str]]:
    """Split subjects into disjoint ``train``, ``validation`` and ``test`` lists.

    With ``n`` subjects off the held-out and training meshes, ``validation`` gets
    ``round(spec.validation * n)`` and ``test`` ``round(spec.test * n)`` of them
    (then shrunk, test first, until at least one subject is left for training);
    ``train`` gets the rest. With ``spec.by == "mesh"`` the same cut is made
    over the meshes, and each subject follows its mesh; with ``"mesh+tissue"``
    also over the tissue settings (``tissue_of``: subject id -> setting name),
    each subject kept where its mesh and tissue agree. ``spec.train_count``
    then shrinks ``train`` (:class:`SplitSpec`). With ``spec.source == "store"``
    they take their part in ``stored`` (the store's split,
    :func:`shared.reader.read_split`) instead. The subjects on
    ``spec.train_meshes`` then join ``train``. The result depends only on the
    *set* of subjects, their meshes, ``spec`` and ``stored`` (input order does
    not matter); each list is sorted.

    Raises
    ------
    InputError
        Duplicate subjects, a subject missing from ``mesh_of`` (or, from the
        store, from ``stored``), a held-out or training mesh that no subject
        uses, or no subject left for training (or, with training meshes, for
        validation and test).
    """
    ids = list(subject_ids)
    if len(set(ids)) != len(ids):
        dupes = sorted({s for s in ids if ids.count(s) > 1})
        raise InputError(f"duplicate subject ids: {', '.join(dupes)}")
    missing = [s for s in ids if s not in mesh_of]
    if missing:
        raise InputError(f"no mesh id given for subject(s): {', '.join(sorted(missing))}")
    used_meshes = {mesh_of[s] for s in ids}
    for kind, meshes in (("held-out", spec.held_out_meshes), ("training", spec.train_meshes)):
        unknown = [m for m in meshes if m not in used_meshes]
        if unknown:
            raise InputError(
                f"{kind} mesh(es) {', '.join(unknown)} not used by any subject; "
                f"meshes are {', '.join(sorted(used_meshes))}"
            )

    held, trained = set(spec.held_out_meshes), set(spec.train_meshes)
    held_out = sorted(s for s in ids if mesh_of[s] in held)
    always_train = sorted(s for s in ids if mesh_of[s] in trained)
    placed = held | trained
    rest = sorted(s for s in ids if mesh_of[s] not in placed)  # sorted first: order of the input must not matter
    if not rest and always_train:
        raise InputError(
            f"no subject left for validation and test: all {len(ids)} subject(s) are on held-out or "
            f"training meshes {', '.join(spec.held_out_meshes + spec.train_meshes)}"
        )
    if not rest:
        raise InputError(
            f"no subject left for training: all {len(ids)} subject(s) are on held-out meshes "
            f"{', '.join(spec.held_out_meshes) or '(none)'}"
        )
    if spec.source == "store":
        if stored is None:
            raise InputError("data.split.source = 'store' needs the store's split (StoreView.stored_split)")
        parts = _stored_parts(rest, held_out, stored)
    else:
        if spec.by == "mesh+tissue":
            parts = _mesh_and_tissue_parts(rest, mesh_of, tissue_of, spec)
        elif spec.by == "mesh":
            parts = _parts_of_units(rest, mesh_of, spec)
        else:
            parts = _cut(rest, spec)
        parts["test"] = sorted(parts["test"] + held_out)
    if spec.train_count:
        parts["train"] = _first_units(parts["train"], mesh_of if spec.by != "subject" else None, spec)
    parts["train"] = sorted(parts["train"] + always_train)
    return parts


def _unit_parts(units: Iterable[str], spec: SplitSpec, salt: int = 0) -> dict[str, str]:
    """Unit -> part of the computed cut of the sorted ``units`` (``salt`` > 0: a shuffle of its own)."""
    cut = _cut(sorted(set(units)), spec if not salt else _salted(spec, salt))
    return {u: part for part, members in cut.items() for u in members}


def _salted(spec: SplitSpec, salt: int) -> SplitSpec:
    return replace(spec, seed=int(np.random.default_rng([spec.seed, salt]).integers(2**31)))


def _parts_of_units(rest: list[str], unit_of: Mapping[str, str], spec: SplitSpec) -> dict[str, list[str]]:
    part_of = _unit_parts((unit_of[s] for s in rest), spec)
    return {part: [s for s in rest if part_of[unit_of[s]] == part] for part in SPLITS}


def _mesh_and_tissue_parts(
    rest: list[str], mesh_of: Mapping[str, str], tissue_of: Mapping[str, str] | None, spec: SplitSpec
) -> dict[str, list[str]]:
    """Subjects whose mesh and tissue fall in the same part of their cuts (module docstring)."""
    if tissue_of is None:
        raise InputError("split by = 'mesh+tissue' needs each subject's tissue setting (StoreView.tissue_of)")
    missing = [s for s in rest if s not in tissue_of]
    if missing:
        raise InputError(f"no tissue setting given for subject(s): {', '.join(sorted(missing))}")
    kept = set(spec.train_tissues)
    unknown = sorted(kept - {tissue_of[s] for s in rest})
    if unknown:
        raise InputError(f"train_tissues {', '.join(unknown)} not used by any subject")
    mesh_part = _unit_parts((mesh_of[s] for s in rest), spec)
    cut = [tissue_of[s] for s in rest if tissue_of[s] not in kept]
    if len(set(cut)) < 2:
        raise InputError("split by = 'mesh+tissue' needs at least 2 tissue settings outside train_tissues")
    tissue_part = _unit_parts(cut, spec, salt=1)
    parts: dict[str, list[str]] = {part: [] for part in SPLITS}
    for s in rest:
        part = mesh_part[mesh_of[s]]
        if tissue_of[s] in kept or tissue_part[tissue_of[s]] == part:
            parts[part].append(s)
    return parts


def _first_units(train: list[str], mesh_of: Mapping[str, str] | None, spec: SplitSpec) -> list[str]:
    """The subjects of the first ``spec.train_count`` training units (meshes, or subjects when ``mesh_of`` is None)."""
    unit = (lambda s: mesh_of[s]) if mesh_of is not None else (lambda s: s)
    units = sorted({unit(s) for s in train})
    if spec.train_count > len(units):
        kind = "anatomies (meshes)" if mesh_of is not None else "subjects"
        raise InputError(f"train_count = {spec.train_count}, but the training part has only {len(units)} {kind}")
    order = np.random.default_rng([spec.seed, len(units)]).permutation(len(units))
    kept = {units[i] for i in order[: spec.train_count]}
    return [s for s in train if unit(s) in kept]


def _cut(items: list[str], spec: SplitSpec) -> dict[str, list[str]]:
    """Shuffle sorted ``items`` by ``spec.seed`` and cut them by the fractions, keeping one for training."""
    n = len(items)
    n_val, n_test = _round_half_up(spec.validation * n), _round_half_up(spec.test * n)
    while n_val + n_test > n - 1:  # keep at least one for training
        if n_test >= n_val:
            n_test -= 1
        else:
            n_val -= 1
    shuffled = [items[i] for i in np.random.default_rng(spec.seed).permutation(n)]
    return {
        "train": sorted(shuffled[n_val + n_test :]),
        "validation": sorted(shuffled[:n_val]),
        "test": sorted(shuffled[n_val : n_val + n_test]),
    }


def _stored_parts(rest: list[str], held_out: list[str], stored: Mapping[str, str]) -> dict[str, list[str]]:
    """``rest`` by their stored part, ``held_out`` added to ``test``."""
    missing = [s for s in rest if stored.get(s) not in SPLITS]
    if missing:
        raise InputError(
            f"data.split.source = 'store', but the store records no split for subject(s) {', '.join(missing)} "
            "(a schema-version-1 store: rebuild it with `simgen build`, or use data.split.source = 'computed')"
        )
    parts = {part: sorted(s for s in rest if stored[s] == part) for part in SPLITS}
    if not parts["train"]:
        raise InputError(f"the store's split leaves no training subject among {len(rest)}; use source = 'computed'")
    parts["test"] = sorted(parts["test"] + held_out)
    return parts
