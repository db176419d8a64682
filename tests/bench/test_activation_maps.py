"""bench.activation_maps' grouping of folds by tissue, which the ECG bench shares."""

from __future__ import annotations

from bench.activation_maps import by_tissue


def test_folds_group_as_all_healthy_and_scarred_and_an_empty_group_is_left_out() -> None:
    folds = [("lv-healthy", [0], [1]), ("lv-scar-apex", [0], [2]), ("biv-healthy", [1], [0])]
    groups = dict(by_tissue(folds, ["a", "b", "c"]))
    assert groups == {"all": ["a", "b", "c"], "healthy": ["a", "c"], "scarred": ["b"]}
    assert [t for t, _ in by_tissue(folds[::2], ["a", "c"])] == ["all", "healthy"]  # one subject's store: no scar
