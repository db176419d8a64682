"""The benchmark's report: Markdown tables, benchmark.json and figures of the numbers of :mod:`learner.benchmark`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from learner.metrics import METRIC_NAMES, activation_times
from learner.plot import plot_activation_panels, plot_context_curves
from learner.store_view import StoreView
from shared.units import MS_PER_TIME_UNIT

__all__ = ["table1", "real_data_table", "write_report"]


def table1(results: dict[str, dict], title: str) -> str:
    """Markdown Table 1: context | target, mean ± std of each metric per method."""
    cols = [m for m in METRIC_NAMES if m != "act_mismatch"]
    head = "| method | " + " | ".join(f"context {m}" for m in cols) + " | " + " | ".join(f"target {m}" for m in cols)
    lines = [f"### {title}\n", head + " |\n", "|---|" + "---|" * (2 * len(cols)) + "\n"]
    for name, res in results.items():
        cells = [_cell(res["overall"].get(role, {}).get(m)) for role in ("context", "target") for m in cols]
        lines.append(f"| {name} | " + " | ".join(cells) + " |\n")
    return "".join(lines)


def _cell(stat: dict | None) -> str:
    if not stat or not np.isfinite(stat["mean"]):
        return "-"
    m, s = stat["mean"], stat["std"]
    return f"{m:.2e} ± {s:.1e}" if abs(m) < 1e-2 else f"{m:.3f} ± {s:.3f}"


def real_data_table(result: dict) -> str:
    """Markdown: one row per method of a :func:`real_data` result."""
    lines = [
        "| method | target mse | target cc_spatial | target cc_temporal | context cc_spatial |",
        "|---|---|---|---|---|",
    ]
    named = {**result["methods"], "noise-free truth (ceiling)": result["ceiling"]}
    for name, r in named.items():
        t, c = r["target"], r["context"]
        lines.append(
            f"| {name} | {_cell(t['mse'])} | {_cell(t['cc_spatial'])} | {_cell(t['cc_temporal'])} "
            f"| {_cell(c['cc_spatial'])} |"
        )
    return "\n".join(lines) + "\n"


def _maps_per_mesh(view: StoreView, rows: list, subjects: list[str], path: Path) -> list[Path]:
    """One figure per subject (``<stem>-<subject>.png``), drawn on that subject's own mesh."""
    paths = []
    for (title, cols), subject in zip(rows, subjects):
        p = path.with_name(f"{path.stem}-{subject}{path.suffix}")
        plot_activation_panels(view.mesh(view.mesh_of[subject]).points, [(title, cols)], p)
        paths.append(p)
    return paths


def _map_row(view: StoreView, example: dict, methods: list[str], subject: str) -> tuple[str, list]:
    """Activation-time maps (ms) of the truth and each method on one target, from the baseline table's run."""
    to_ms = lambda u: activation_times(u, view.times) * MS_PER_TIME_UNIT  # noqa: E731
    cols = [("truth", to_ms(example["truth"]))] + [(name, to_ms(example[name])) for name in methods]
    return (f"{subject}, site {example['site']}", cols)


def write_report(results: dict, out: Path, view: StoreView, examples: dict[str, dict], noise_draws: int) -> None:
    """Write ``<out>/``: benchmark.md, table1.md, timing.md, benchmark.json, fig3_context.png, activation maps.

    ``examples``: per subject of ``results["maps"]``, the truth and each method's prediction of one target
    (:func:`~learner.evaluate.evaluate_methods`); ``noise_draws``: model-error draws per c of the calibration.
    """
    plot_context_curves(results["fig3"], out / "fig3_context.png")
    rows = []
    for subject in results["maps"]:
        methods = [name for name in examples[subject] if name not in ("site", "truth")]
        rows.append(_map_row(view, examples[subject], methods, subject))
    _maps_per_mesh(view, rows, results["maps"], out / "activation_maps.png")
    maps = "".join(f"![activation maps](activation_maps-{s}.png)\n" for s in results["maps"])
    md = [
        "# Benchmark\n\n",
        table1(
            results["table1_all_test"], f"Table 1: all {len(results['test_subjects'])} test subjects (metaPNS, PNS)"
        ),
        "\n",
        table1(results["table1_baseline_subset"], "Table 1: the baseline subset, same context sets for every method"),
        "\n![accuracy vs context size](fig3_context.png)\n\n### Timing (CPU)\n\n| step | seconds | simulator calls |\n"
        "|---|---|---|\n",
    ]
    timing = [
        f"| {name} | {row['seconds']:.4g} | {row.get('simulator calls', '')} |\n"
        for name, row in results["timing"].items()
    ]
    md += timing
    (out / "timing.md").write_text("| step | seconds | simulator calls |\n|---|---|---|\n" + "".join(timing))
    c = results["calibration"]
    md.append(
        f"\n### Uncertainty\n\n{c['samples']} draws of c ~ p(c | Y), each with {noise_draws} draws of the "
        f"subject's context misfit N(0, s^2): the truth lies inside the 5-95% band for "
        f"{100 * c['coverage_90']:.1f}% of target values (ideal 90%; mean band width "
        f"{c['mean_band_width']:.3f}). From c alone: {100 * c['coverage_90_c_only']:.1f}% (width "
        f"{c['mean_band_width_c_only']:.3f}).\n"
    )
    md.append(f"\n### Activation maps (truth vs predictions, one target site)\n\n{maps}")
    if "real_data" in results:
        r = results["real_data"]
        sites = results["config"]["real_data"]["sites"]
        md.append(
            f"\n### Real-data emulation\n\nUnseen geometry {', '.join(r['subjects'])}, {r['electrodes']} sock "
            f"electrodes, noise {r['noise_std']}, each of {sites} pacing sites left out in turn:\n\n"
            + real_data_table(r)
        )
    if "real_data_baseline_subset" in results:
        folds = results["config"]["real_data"]["baseline_folds"]
        md.append(
            f"\nThe BO baselines on the first {folds} left-out site(s) of each subject, every method on the same "
            f"folds:\n\n" + real_data_table(results["real_data_baseline_subset"])
        )
    (out / "benchmark.md").write_text("".join(md))
    (out / "table1.md").write_text(
        table1(results["table1_all_test"], "all test subjects")
        + "\n"
        + table1(results["table1_baseline_subset"], "baseline subset")
    )
    (out / "benchmark.json").write_text(json.dumps(results, indent=1, default=float))
