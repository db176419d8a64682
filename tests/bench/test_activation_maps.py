"""bench.activation_maps' grouping of folds by tissue, which the ECG bench shares, and its table."""

from __future__ import annotations

import numpy as np
import pytest

from bench.activation_maps import by_tissue, summary, table


def test_folds_group_as_all_healthy_and_scarred_and_an_empty_group_is_left_out() -> None:
    folds = [("lv-healthy", [0], [1]), ("lv-scar-apex", [0], [2]), ("biv-healthy", [1], [0])]
    groups = dict(by_tissue(folds, ["a", "b", "c"]))
    assert groups == {"all": ["a", "b", "c"], "healthy": ["a", "c"], "scarred": ["b"]}
    assert [t for t, _ in by_tissue(folds[::2], ["a", "c"])] == ["all", "healthy"]  # one subject's store: no scar


def test_the_summary_and_table_give_every_reading_of_the_maps_a_model_has() -> None:
    fold = {
        "potentials": {"cc": [0.8, 0.6], "error_ms": [10.0, 20.0]},
        "activation": {"cc": [0.7, 0.7], "error_ms": [12.0, np.nan]},
    }
    row = {"hearts": "real", "tissue": "all", "observe": "electrodes", **summary([fold])}
    assert row["difference"] == pytest.approx(0.0) and row["activation"]["error_ms"] == 12.0 and row["targets"] == 2
    lines = table([row])
    assert lines[0].count("|") == lines[1].count("|") == lines[2].count("|") == 9 and "0.700" in lines[2]
    fold["every_frame"] = {"cc": [0.5, 0.3], "error_ms": [15.0, 15.0]}
    row = {**row, **summary([fold])}
    lines = table([row])
    assert lines[0].count("|") == lines[1].count("|") == lines[2].count("|") == 10
    assert "| 0.400 (-0.300) |" in lines[2]
