"""Where a model's target error comes from: targets grouped by the tissue at their stimulation site.

A stimulus inside a scar core launches a wave only where the core can still be
excited (about a third of the core sites of the default store), so a model
that predicts the wrong one of the two is wrong at nearly every node and frame
(activation mismatch near 1). This script reads the ``evaluation.json`` that
``learner evaluate`` writes and the store it evaluated, labels every target by
the tissue at its site (healthy, border zone, core; the core split by whether
the stored simulation started a wave), and prints per group: the number of
targets, their mean MSE and spatial CC, the share of all target error they
carry, and how many are mismatched (activation mismatch > 0.5).
With ``--checkpoints`` (one per report, models with ``model.capture_gate``) it
also gives the mean capture gate of each group: the model's probability that a
stimulus there starts a wave, from the same context sets.
docs/training.md ("Where the error is") publishes the table.

Run::

    learner evaluate runs/seed0/best.pt data/default.zarr --sets 1 --max-targets 20 --out report/eval-seed0
    .venv/bin/python -m bench.site_tissue_errors data/default.zarr report/eval-seed0 [more reports] \
        [--checkpoints runs/seed0/best.pt ...] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from bench.common import add_out_argument, write_out
from learner.data.episodes import load_episode
from learner.metrics import wave_started
from learner.models.site_evidence import SiteEvidence
from learner.store_view import StoreView
from learner.train.trainer import load_model
from shared.reader import read_tissue, read_u
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


def site_rows(view: StoreView, subject: str) -> dict[int, int]:
    """A subject's stimulation node ids mapped to their site rows in the store."""
    return {int(node): i for i, node in enumerate(view.sites(view.mesh_of[subject]))}


def waves_started(store: str, rows: list[dict]) -> np.ndarray:
    """Whether each row's stimulus started a wave in the stored simulation (:func:`learner.metrics.wave_started`)."""
    view = StoreView(store)
    started: dict[tuple[str, int], bool] = {}
    for subject in dict.fromkeys(r["subject"] for r in rows):
        row_of = site_rows(view, subject)
        nodes = sorted({r["site"] for r in rows if r["subject"] == subject})
        waves = wave_started(read_u(store, subject, [row_of[n] for n in nodes]))
        started.update({(subject, n): bool(w) for n, w in zip(nodes, waves, strict=True)})
    return np.array([started[r["subject"], r["site"]] for r in rows])


def capture_gates(store: str, rows: list[dict], checkpoint: str) -> np.ndarray:
    """The model's capture gate for each target row, in order, from the context set it was evaluated with."""
    model, config, _ = load_model(checkpoint)
    if model.capture is None:
        raise SystemExit(f"{checkpoint} has no capture gate (model.capture_gate is off)")
    view = StoreView(store, cache_dir=Path(checkpoint).parent / "hierarchies")
    groups: dict[tuple[str, int], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["subject"], r["set"]), []).append(r)
    gates: dict[tuple[str, int, int], float] = {}
    for (subject, context_set), group in groups.items():
        row_of = site_rows(view, subject)
        context = [row_of[r["site"]] for r in group if r["role"] == "context"]
        targets = [r["site"] for r in group if r["role"] == "target"]
        ep = load_episode(store, subject, context, [row_of[t] for t in targets], config.data.episodes.primary_observe)
        hier = view.hierarchy(view.mesh_of[subject], config.model.levels, config.model.coarsest)
        with torch.no_grad():
            c = model.embed(ep.context_obs, ep.observed, hier).mu
            g = model.capture_probability(ep.target_sites, hier, c, SiteEvidence.of(ep)).tolist()
        gates.update({(subject, context_set, site): value for site, value in zip(targets, g, strict=True)})
    return np.array([gates[r["subject"], r["set"], r["site"]] for r in rows if r["role"] == "target"])


def tissue_table(store: str, reports: dict[str, dict], checkpoints: dict[str, str] | None = None) -> str:
    """Markdown: one row per (model, site label); with ``checkpoints`` also the mean capture gate."""
    gate_column = bool(checkpoints)
    lines = [
        "| model | site tissue | targets | mean MSE | mean CC | share of target error | mismatched |"
        + (" mean capture gate |" if gate_column else ""),
        "|---|---|---:|---:|---:|---:|---:|" + ("---:|" if gate_column else ""),
    ]
    for name, report in reports.items():
        rows = report["rows"]
        targets = [r for r in rows if r["role"] == "target"]
        labels = np.array(site_labels(store, targets))
        mse = np.array([r["mse"] for r in targets])
        cc = np.array([r["cc_spatial"] for r in targets], dtype=float)
        bad = np.array([r["act_mismatch"] > MISMATCHED for r in targets])
        gates = capture_gates(store, rows, checkpoints[name]) if gate_column else None
        core = labels == LABEL_CORE
        started = waves_started(store, targets)
        groups = [(labels == label, text) for label, text in LABELS.items()]
        groups += [(core & started, "scar core, a wave starts"), (core & ~started, "scar core, no wave")]
        for sel, text in [*groups, (np.ones(len(targets), dtype=bool), "all")]:
            if not sel.any():
                continue
            line = (
                f"| {name} | {text} | {sel.sum()} | {mse[sel].mean():.4f} | {np.nanmean(cc[sel]):.3f} "
                f"| {mse[sel].sum() / mse.sum():.0%} | {bad[sel].sum()} |"
            )
            lines.append(line + (f" {gates[sel].mean():.2f} |" if gates is not None else ""))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the store the reports evaluated")
    parser.add_argument("reports", nargs="+", type=Path, help="directories holding evaluation.json")
    parser.add_argument("--checkpoints", nargs="*", default=[], help="the evaluated models, one per report")
    add_out_argument(parser, "site_tissue_errors")
    args = parser.parse_args()
    if args.checkpoints and len(args.checkpoints) != len(args.reports):
        parser.error(f"give one checkpoint per report ({len(args.reports)}), got {len(args.checkpoints)}")
    reports = {p.name: json.loads((p / "evaluation.json").read_text()) for p in args.reports}
    checkpoints = dict(zip(reports, args.checkpoints, strict=False)) if args.checkpoints else None
    table = tissue_table(args.store, reports, checkpoints)
    print(table)
    write_out(args.out, "site_tissue_errors", table + "\n")


if __name__ == "__main__":
    main()
