"""Subject splits: disjoint, covering, deterministic, held-out meshes to test."""

from __future__ import annotations

from dataclasses import replace

import pytest

from learner.data import SPLITS, SplitSpec, split_subjects
from shared.errors import InputError


def _mesh_of(ids: list[str]) -> dict[str, str]:
    """Each subject's mesh: the part of its id before the first dash."""
    return {sid: sid.split("-")[0] for sid in ids}


IDS = [f"m{m}-s{s:02d}" for m in range(3) for s in range(20)]
MESH_OF = _mesh_of(IDS)
ANATOMY_IDS = [f"a{m:02d}-s{s}" for m in range(20) for s in range(4)]  # 20 anatomies x 4 tissue settings


def _check_partition(parts: dict[str, list[str]], ids: list[str]) -> None:
    assert set(parts) == set(SPLITS)
    together = [s for name in SPLITS for s in parts[name]]
    assert sorted(together) == sorted(ids)  # covering, and no subject twice (disjoint)
    assert all(parts[name] == sorted(parts[name]) for name in SPLITS)


def test_partition_counts_and_determinism():
    spec = SplitSpec(seed=3, validation=0.1, test=0.2)
    parts = split_subjects(IDS, MESH_OF, spec)
    _check_partition(parts, IDS)
    assert (len(parts["train"]), len(parts["validation"]), len(parts["test"])) == (42, 6, 12)
    assert split_subjects(list(reversed(IDS)), MESH_OF, spec) == parts  # input order is irrelevant
    assert split_subjects(IDS, MESH_OF, SplitSpec(seed=4)) != parts


def test_held_out_meshes_all_go_to_test():
    spec = SplitSpec(seed=0, validation=0.25, test=0.25, held_out_meshes=["m1"])
    assert spec.held_out_meshes == ("m1",)
    parts = split_subjects(IDS, MESH_OF, spec)
    _check_partition(parts, IDS)
    on_m1 = {s for s in IDS if MESH_OF[s] == "m1"}
    assert on_m1 <= set(parts["test"])
    assert not on_m1 & (set(parts["train"]) | set(parts["validation"]))
    # fractions apply to the 40 subjects not held out: round(10) each
    assert (len(parts["train"]), len(parts["validation"]), len(parts["test"])) == (20, 10, 30)


def test_rounding_keeps_one_training_subject():
    parts = split_subjects(["a"], {"a": "m"}, SplitSpec(validation=0.3, test=0.6))
    assert parts == {"train": ["a"], "validation": [], "test": []}
    parts = split_subjects(["a", "b"], {"a": "m", "b": "m"}, SplitSpec(validation=0.45, test=0.5))
    assert len(parts["train"]) == 1 and len(parts["validation"]) == 1 and parts["test"] == []


@pytest.mark.parametrize(
    "ids, mesh_of, spec, match",
    [
        (["a"], {"a": "m"}, SplitSpec(held_out_meshes=("m",)), "no subject left for training"),
        (["a"], {"a": "m"}, SplitSpec(held_out_meshes=("x",)), "held-out mesh.*x.*not used"),
        (["a"], {"a": "m"}, SplitSpec(train_meshes=("x",)), "training mesh.*x.*not used"),
        (["a"], {"a": "m"}, SplitSpec(train_meshes=("m",)), "no subject left for validation and test"),
        (["a", "b"], {"a": "m"}, SplitSpec(), "no mesh id given for subject.*b"),
        (["a", "a"], {"a": "m"}, SplitSpec(), "duplicate subject ids: a"),
    ],
)
def test_refusals(ids, mesh_of, spec, match):
    with pytest.raises(InputError, match=match):
        split_subjects(ids, mesh_of, spec)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"validation": 0.5, "test": 0.5}, "must be < 1"),
        ({"test": -0.1}, r"test fraction must be in \[0, 1\)"),
        ({"validation": 1.0}, r"validation fraction must be in \[0, 1\)"),
        ({"seed": -1}, "non-negative integer"),
        ({"held_out_meshes": "lv"}, "list of mesh ids"),
        ({"train_meshes": "lv"}, "list of mesh ids"),
        ({"train_meshes": ["lv"], "held_out_meshes": ["lv"]}, "lv are both held out and training"),
    ],
)
def test_bad_spec(kwargs, match):
    with pytest.raises(InputError, match=match):
        SplitSpec(**kwargs)


def test_stored_split_takes_the_parts_the_store_records():
    stored = {sid: ("test" if sid.endswith("0") else "validation" if sid.endswith("1") else "train") for sid in IDS}
    parts = split_subjects(IDS, MESH_OF, SplitSpec(source="store", held_out_meshes=("m2",)), stored)
    _check_partition(parts, IDS)
    assert parts["validation"] == sorted(s for s in IDS if s.endswith("1") and MESH_OF[s] != "m2")
    assert parts["test"] == sorted(s for s in IDS if s.endswith("0") or MESH_OF[s] == "m2")
    other = SplitSpec(source="store", seed=5, test=0.5)  # seed and fractions do not apply
    assert split_subjects(IDS, MESH_OF, other, stored) == split_subjects(
        IDS, MESH_OF, SplitSpec(source="store"), stored
    )


@pytest.mark.parametrize(
    "stored, match",
    [
        (None, "needs the store's split"),
        ({"a": "train"}, "records no split for subject.*b.*rebuild it with `simgen build`"),
        ({"a": "test", "b": "validation"}, "leaves no training subject"),
    ],
)
def test_stored_split_refusals(stored, match):
    with pytest.raises(InputError, match=match):
        split_subjects(["a", "b"], {"a": "m", "b": "m"}, SplitSpec(source="store"), stored)


def test_unknown_split_source_is_refused():
    with pytest.raises(InputError, match="split source must be 'computed' or 'store'"):
        SplitSpec(source="file")


def test_adding_a_subject_moves_no_stored_subject(store_copy):
    from learner.store_view import StoreView
    from simgen.store.edit import add_subject
    from simgen.store.spec import MeshEntry

    spec = SplitSpec(source="store")
    view = StoreView(store_copy)
    before = split_subjects(view.subjects, view.mesh_of, spec, view.stored_split)
    assert sum(map(len, before.values())) == 6 and before["train"]
    add_subject(store_copy, MeshEntry(id="extra", source="lv", nodes=500), ["healthy", "scar-apex"], workers=1)
    view = StoreView(store_copy)
    after = split_subjects(view.subjects, view.mesh_of, spec, view.stored_split)
    for part in SPLITS:
        assert set(before[part]) <= set(after[part])
    assert sum(map(len, after.values())) == 8


@pytest.mark.parametrize("seed", range(5))
def test_split_by_mesh_keeps_anatomies_whole(seed):
    ids, mesh_of = ANATOMY_IDS, _mesh_of(ANATOMY_IDS)
    parts = split_subjects(ids, mesh_of, SplitSpec(seed=seed, validation=0.1, test=0.2, by="mesh"))
    _check_partition(parts, ids)
    meshes = {name: {mesh_of[s] for s in parts[name]} for name in SPLITS}
    assert not meshes["train"] & meshes["test"] and not meshes["train"] & meshes["validation"]
    assert not meshes["validation"] & meshes["test"]
    assert (len(meshes["train"]), len(meshes["validation"]), len(meshes["test"])) == (14, 2, 4)
    assert all(len(parts[name]) == 4 * len(meshes[name]) for name in SPLITS)  # every tissue of an anatomy


def test_split_by_mesh_with_held_out_mesh_and_one_mesh_left():
    parts = split_subjects(IDS, MESH_OF, SplitSpec(validation=0.3, test=0.3, by="mesh", held_out_meshes=("m2",)))
    meshes = {name: {MESH_OF[s] for s in parts[name]} for name in SPLITS}
    assert meshes["test"] == {"m2"} and len(meshes["train"]) == len(meshes["validation"]) == 1


def test_train_count_keeps_nested_anatomies_and_the_same_validation_and_test():
    ids, mesh_of = ANATOMY_IDS, _mesh_of(ANATOMY_IDS)
    full = split_subjects(ids, mesh_of, SplitSpec(seed=3, by="mesh"))
    kept = {}
    for count in (1, 4, 14):
        parts = split_subjects(ids, mesh_of, SplitSpec(seed=3, by="mesh", train_count=count))
        assert parts["validation"] == full["validation"] and parts["test"] == full["test"]
        kept[count] = {mesh_of[s] for s in parts["train"]}
        assert len(kept[count]) == count and len(parts["train"]) == 4 * count  # every tissue of a kept anatomy
    assert kept[1] < kept[4] < kept[14] == {mesh_of[s] for s in full["train"]}
    by_subject = split_subjects(ids, mesh_of, SplitSpec(seed=3, train_count=5))
    assert len(by_subject["train"]) == 5


@pytest.mark.parametrize("train_count", [0, 3])
def test_training_meshes_join_train_and_leave_validation_and_test_as_they_were(train_count):
    ids, mesh_of = ANATOMY_IDS, _mesh_of(ANATOMY_IDS)
    real = [f"{m}-s{s}" for m in ("real1", "real2") for s in range(4)]
    spec = SplitSpec(seed=2, by="mesh", train_count=train_count)
    before = split_subjects(ids, mesh_of, spec)
    after = split_subjects(ids + real, _mesh_of(ids + real), replace(spec, train_meshes=("real1", "real2")))
    if not train_count:  # train_count leaves training anatomies out: no partition of all subjects then
        _check_partition(after, ids + real)
    assert after["validation"] == before["validation"] and after["test"] == before["test"]
    assert after["train"] == sorted(before["train"] + real)


def test_train_count_above_the_training_part_is_refused():
    with pytest.raises(InputError, match="train_count = 15, but the training part has only 14 anatomies"):
        split_subjects(ANATOMY_IDS, _mesh_of(ANATOMY_IDS), SplitSpec(by="mesh", train_count=15))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"by": "site"}, "split by must be 'subject', 'mesh' or 'mesh\\+tissue'"),
        ({"by": "mesh+tissue", "source": "store"}, "per subject"),
        ({"train_tissues": ["healthy"]}, "set by = 'mesh\\+tissue'"),
        ({"by": "mesh", "source": "store"}, "per subject"),
        ({"train_count": -1}, "train_count must be >= 0"),
        ({"train_count": 2.5}, "train_count must be an integer"),
    ],
)
def test_split_by_bad_values(kwargs, message):
    with pytest.raises(InputError, match=message):
        SplitSpec(**kwargs)


def _prior_ids(meshes: int = 20, draws: int = 10) -> tuple[list[str], dict[str, str], dict[str, str]]:
    """Subjects of ``meshes`` anatomies x (2 named settings + ``draws`` drawn ones)."""
    tissues = ["healthy", "scar-apex", *(f"draw-{i:03d}" for i in range(draws))]
    pairs = [(f"m{m:02d}", t) for m in range(meshes) for t in tissues]
    ids = [f"{m}-{t}" for m, t in pairs]
    return ids, {i: m for i, (m, _) in zip(ids, pairs)}, {i: t for i, (_, t) in zip(ids, pairs)}


def test_split_by_mesh_and_tissue_holds_out_anatomies_and_draws():
    ids, mesh_of, tissue_of = _prior_ids()
    spec = SplitSpec(validation=0.1, test=0.2, by="mesh+tissue", train_tissues=("healthy", "scar-apex"))
    parts = split_subjects(ids, mesh_of, spec, tissue_of=tissue_of)
    meshes = {name: {mesh_of[s] for s in parts[name]} for name in SPLITS}
    draws = {name: {tissue_of[s] for s in parts[name]} - {"healthy", "scar-apex"} for name in SPLITS}
    # the mesh cut is the one of by = "mesh": a model trained by mesh alone holds out the same anatomies
    by_mesh = split_subjects(ids, mesh_of, replace(spec, by="mesh", train_tissues=()))
    assert meshes == {name: {mesh_of[s] for s in by_mesh[name]} for name in SPLITS}
    assert (len(draws["train"]), len(draws["validation"]), len(draws["test"])) == (7, 1, 2)
    for a, b in (("train", "validation"), ("train", "test"), ("validation", "test")):
        assert not meshes[a] & meshes[b] and not draws[a] & draws[b]
    # every named setting in every part; a subject pairing a training mesh with a test draw is in no part
    assert all({"healthy", "scar-apex"} <= {tissue_of[s] for s in parts[name]} for name in SPLITS)
    assert sum(map(len, parts.values())) == 14 * 9 + 2 * 3 + 4 * 4
    assert split_subjects(list(reversed(ids)), mesh_of, spec, tissue_of=tissue_of) == parts


def test_split_by_mesh_and_tissue_refusals():
    ids, mesh_of, tissue_of = _prior_ids(meshes=4, draws=1)
    spec = SplitSpec(by="mesh+tissue")
    with pytest.raises(InputError, match="needs each subject's tissue"):
        split_subjects(ids, mesh_of, spec)
    with pytest.raises(InputError, match="no tissue setting given"):
        split_subjects(ids, mesh_of, spec, tissue_of={})
    with pytest.raises(InputError, match="train_tissues scar-x not used"):
        split_subjects(ids, mesh_of, replace(spec, train_tissues=("scar-x",)), tissue_of=tissue_of)
    with pytest.raises(InputError, match="at least 2 tissue settings"):
        split_subjects(ids, mesh_of, replace(spec, train_tissues=("healthy", "scar-apex")), tissue_of=tissue_of)
