"""Where a model's target error comes from: targets grouped by the tissue at their stimulation site.

A stimulus inside a scar core launches no wave (the core is not excitable), so
a model that predicts a wave there is wrong at nearly every node and frame
(activation mismatch near 1). This script reads the ``evaluation.json`` that
``learner evaluate`` writes and the store it evaluated, labels every target by
the tissue at its site (healthy, border zone, core), and prints per label: the
number of targets, their mean MSE and spatial CC, the share of all target
error they carry, and how many are mismatched (activation mismatch > 0.5).
docs/training.md ("Where the error is") publishes the table.

Run::

    learner evaluate runs/seed0/best.pt data/default.zarr --sets 1 --max-targets 20 --out report/eval-seed0
    .venv/bin/python bench/site_tissue_errors.py data/default.zarr report/eval-seed0 [more reports] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from shared.reader import read_tissue
from shared.tissue import LABEL_BORDER, LABEL_CORE, LABEL_HEALTHY

LABELS = {LABEL_HEALTHY: "healthy", LABEL_BORDER: "border zone", LABEL_CORE: "scar core"}
MISMATCHED = 0.5  # activation mismatch above which a target's wave is wrong, not late


def site_labels(store: str, rows: list[dict]) -> list[int]:
    """The tissue label at each row's stimulation site."""
    tissue: dict[str, np.ndarray] = {}
    for r in rows:
        if r["subject"] not in tissue:
            tissue[r["subject"]] = read_tissue(store, r["subject"]).label
    return [int(tissue[r["subject"]][r["site"]]) for r in rows]


def tissue_table(store: str, reports: dict[str, dict]) -> str:
    """Markdown: one row per (model, site label)."""
    lines = [
        "| model | site tissue | targets | mean MSE | mean CC | share of target error | mismatched |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, report in reports.items():
        rows = [r for r in report["rows"] if r["role"] == "target"]
        labels = np.array(site_labels(store, rows))
        mse = np.array([r["mse"] for r in rows])
        cc = np.array([r["cc_spatial"] for r in rows], dtype=float)
        bad = np.array([r["act_mismatch"] > MISMATCHED for r in rows])
        for label, text in LABELS.items():
            sel = labels == label
            if not sel.any():
                continue
            lines.append(
                f"| {name} | {text} | {sel.sum()} | {mse[sel].mean():.4f} | {np.nanmean(cc[sel]):.3f} "
                f"| {mse[sel].sum() / mse.sum():.0%} | {bad[sel].sum()} |"
            )
        lines.append(f"| {name} | all | {len(rows)} | {mse.mean():.4f} | {np.nanmean(cc):.3f} | 100% | {bad.sum()} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the store the reports evaluated")
    parser.add_argument("reports", nargs="+", type=Path, help="directories holding evaluation.json")
    parser.add_argument("--out", type=Path, help="write site_tissue_errors.md there")
    args = parser.parse_args()
    reports = {p.name: json.loads((p / "evaluation.json").read_text()) for p in args.reports}
    table = tissue_table(args.store, reports)
    print(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "site_tissue_errors.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
