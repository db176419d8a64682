"""Spread of Table 1 over training seeds: one row per model, then mean +- std over the models.

Reads the ``evaluation.json`` that ``learner evaluate`` writes for each model
(same store, subjects and context sets), and prints target and context MSE,
spatial CC and DC of each, then the mean and (sample) standard deviation of the
per-model means: how much of a result is the seed's. The table is published in docs/training.md
("Table 1 over the three seeds").

Run (after training one model per seed)::

    for s in 0 1 2; do learner evaluate runs/seed$s/best.pt data/default.zarr --sets 1 --max-targets 20 \\
        --out report/eval-seed$s; done
    .venv/bin/python -m bench.seed_spread report/eval-seed0 report/eval-seed1 report/eval-seed2 [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from bench.common import add_out_argument, write_out

COLUMNS = (
    ("target", "mse"),
    ("target", "cc_spatial"),
    ("target", "dc"),
    ("context", "mse"),
    ("context", "cc_spatial"),
    ("context", "dc"),
)


def spread_table(reports: dict[str, dict]) -> str:
    """Markdown: a row per model (its mean over test sequences), then mean +- std over the models."""
    header = "| model | " + " | ".join(f"{role} {metric}" for role, metric in COLUMNS) + " |"
    lines = [header, "|---" * (len(COLUMNS) + 1) + "|"]
    values = {col: [] for col in COLUMNS}
    for name, report in reports.items():
        row = []
        for role, metric in COLUMNS:
            v = report["overall"][role][metric]["mean"]
            values[(role, metric)].append(v)
            row.append(f"{v:.3f}")
        lines.append(f"| {name} | " + " | ".join(row) + " |")
    spread = [f"{statistics.mean(v):.3f} ± {statistics.stdev(v) if len(v) > 1 else 0.0:.3f}" for v in values.values()]
    lines.append(f"| mean ± std over {len(reports)} models | " + " | ".join(spread) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("evaluations", type=Path, nargs="+", help="folders holding evaluation.json")
    add_out_argument(parser, "seed_spread")
    args = parser.parse_args()
    reports = {}
    for folder in args.evaluations:
        path = folder / "evaluation.json"
        if not path.is_file():
            parser.error(f"{path} not found (run `learner evaluate ... --out {folder}` first)")
        reports[folder.name] = json.loads(path.read_text())
    table = spread_table(reports)
    print(table)
    write_out(args.out, "seed_spread", table + "\n")


if __name__ == "__main__":
    main()
