"""bench.tissue_families: per-family means, the share of the ceiling over the same folds, and the tables."""

from __future__ import annotations

import math

import pytest

from bench.tissue_families import markdown, summarise
from shared.tissue import ScarSpec
from simgen.tissue.report import scar_location


def _rows() -> list[dict]:
    rows = []
    for subject, family, cc in (("a", "slower", 0.6), ("b", "faster", 0.8)):
        for left in range(2):
            fold = {"subject": subject, "heart": "h", "family": family, "left_out": left}
            rows.append({**fold, "method": "ceiling", "cc": 1.0 if left == 0 else 0.5})
            rows.append({**fold, "method": "m", "cc": cc, "activation_ms": 10.0 * (left + 1)})
            if left == 0:  # FS-BO on the first fold only: its share is against that fold's ceiling
                rows.append(
                    {**fold, "method": "fs-bo", "cc": 0.5, "activation_ms": 5.0, "tissue_dice": 0.4, "cv_error": 0.2}
                )
    return rows


def test_summary_by_hand() -> None:
    summary = summarise(_rows())
    slower = summary["h | slower"]
    assert slower["subjects"] == 1 and slower["ceiling_cc"] == pytest.approx(0.75)
    assert slower["methods"]["m"]["share"] == pytest.approx(0.6 / 0.75)
    assert slower["methods"]["m"]["activation_ms"] == pytest.approx(15.0)
    assert slower["methods"]["fs-bo"]["share"] == pytest.approx(0.5 / 1.0)
    assert math.isnan(slower["methods"]["m"]["tissue_dice"])
    whole = summary["h | all"]
    assert whole["subjects"] == 2 and whole["methods"]["m"]["cc"] == pytest.approx(0.7)
    assert whole["methods"]["fs-bo"]["tissue_dice"] == pytest.approx(0.4)
    table = markdown(summary, ["m", "fs-bo"])
    assert "| h | slower | 1 | 0.750 | 0.600 (80%) | 15.0 | 0.500 (50%) | 5.0 |" in table
    assert "| h | slower | - | - | 0.40 | 20% |" in table


@pytest.mark.parametrize(
    ("ventricle", "height", "angle", "words"),
    [
        ("lv", 0.5, 90.0, "LV anterior mid"),
        ("lv", 0.1, -100.0, "LV inferior apical"),
        ("lv", 0.8, 170.0, "LV lateral basal"),
        ("lv", 0.5, -170.0, "LV lateral mid"),
        ("lv", 0.4, 10.0, "LV septal mid"),
        ("rv", 0.9, 30.0, "RV free wall basal"),
    ],
)
def test_scar_location_names_sector_and_level(ventricle, height, angle, words) -> None:
    scar = ScarSpec(region="wall", ventricle=ventricle, height=height, angle=angle, radius=10.0)
    assert scar_location(scar) == words
    assert scar_location(ScarSpec(region="segments", segments=(7,))) == "AHA 7"
