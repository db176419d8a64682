"""Benchmark: personalisation per tissue family, and what each method infers about the tissue.

On the store of ``--store`` (``specs/benchmark-prior.toml``: 6 sampled anatomies no model has seen and the three
shipped real hearts, each under 11 tissue settings drawn family by family from the tissue prior), every method
personalises on 7 of a subject's 8 epicardial pacing sites, observed through the 247-electrode sock with noise
0.02, and predicts the 8th (the folds, noise draws and sock of ``learner.benchmark.real_data``). Per heart
(the unseen sampled anatomies together, each real heart alone) and tissue family (slower, faster, one scar
named by its location, several scars, fibrosis) it reports:

* spatial CC at the electrodes against the noisy recording of the left-out site, and its share of the ceiling
  (the noise-free truth scored the same way: what a perfect method gets);
* the activation error (ms) of the full-mesh prediction against the true activation times, over the nodes
  activated in both (``learner.metrics.activation_error_ms``);
* for methods that estimate tissue (a model with a tissue head, FS-BO), on each subject's first fold: the Dice
  coefficient of the abnormal region (scar core and border zone) against the drawn truth, and the relative
  error of the healthy tissue's conduction velocity against the one measured on a strip
  (``simgen.tissue.tune.physical``). FS-BO's abnormal region is its regions fitted as border or core, its CV
  that of its most excitable region.

``--model NAME=CKPT`` adds a trained model (a shipped name such as ``anatomies`` or a checkpoint);
``--fs-bo-folds N`` runs FS-BO (budget 100 simulator calls, 7 regions) on the first N folds of each subject.
``--test-store STORE --split-from CKPT`` also scores each model on that checkpoint's test subjects of its
training store (unseen anatomies x unseen tissue draws, and the named settings on unseen anatomies),
surface-observed as ``learner evaluate`` does, family by family.

Run::

    .venv/bin/python -m bench.tissue_families --store data/benchmark-prior.zarr \\
        --model old=learner/pretrained/anatomies --model new=anatomies --fs-bo-folds 1 \\
        --test-store data/pretrained-prior.zarr --split-from runs/prior/best.pt --out report/bench

``--out DIR`` writes tissue_families.md and tissue_families.json; ``--publish`` writes the tables into the
block ``tissue_families`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import torch

from bench.common import add_out_argument, add_publish_argument, check_publish, publish_out, write_out
from learner.baselines.base import diffusivity_from_excitability
from learner.benchmark import observe_fold
from learner.checkpoint import load_checkpoint
from learner.evaluate import EvalSpec, Method, NeuralMethod, evaluate, load_method
from learner.methods import MethodContext, build_methods
from learner.metrics import activation_error_ms, activation_times, spatial_cc
from learner.models.surrogate import MetaPNS
from learner.store_view import StoreView
from learner.tissue_estimate import TissueEstimate, estimate_tissue, tissue_scores
from shared.observation import Observation
from shared.reader import read_solver_settings, read_tissue, subject_attrs
from shared.tissue import ABNORMAL_LABELS, Material, TissueSpec, healthy_speed
from simgen.store.spec import spec_from_mapping
from simgen.tissue import tissue_spec_from_mapping
from simgen.tissue.report import scar_location, tissue_family
from simgen.tissue.tune import physical

#: The shipped real hearts: each is reported alone, every other mesh with the unseen sampled anatomies.
REAL_HEARTS = ("tof-biv", "rodero01-lv", "cobiveco-mean-biv")
SAMPLED = "unseen sampled"
OBSERVATION = Observation("electrodes", 0.02)
TISSUE_DRAWS = 16


@dataclass(frozen=True)
class Truth:
    """What a subject's tissue is: its family (a single scar named by where it lies), abnormal nodes and CV."""

    heart: str
    family: str
    abnormal: np.ndarray
    cv: float


def subject_truth(view: StoreView, subject: str) -> Truth:
    """The drawn truth of ``subject`` (module docstring)."""
    solver = spec_from_mapping(view.attrs["spec"]).solver
    tissue = tissue_spec_from_mapping(subject_attrs(view.store, subject)["tissue"])
    family = tissue_family(tissue, solver)
    if family == "one scar":
        family = f"one scar, {scar_location(tissue.scars[0])}"
    mesh_id = view.mesh_of[subject]
    label = read_tissue(view.store, subject).label
    return Truth(
        mesh_id if mesh_id in REAL_HEARTS else SAMPLED,
        family,
        np.isin(label, ABNORMAL_LABELS),
        physical(tissue, solver).cv,
    )


def neural_tissue(method: NeuralMethod, episode, hierarchy, mesh) -> TissueEstimate | None:
    """The tissue head's estimate from the episode's context (None for a model without one)."""
    model = method.model
    if not isinstance(model, MetaPNS) or model.tissue_head is None:
        return None
    with torch.no_grad():
        posterior = model.embed(episode.context_obs, episode.observed, hierarchy)
    return estimate_tissue(model, posterior, hierarchy, mesh, TISSUE_DRAWS)


def fs_bo_tissue(method: Method, mesh, diffusivity: float) -> TissueEstimate:
    """FS-BO's fitted tissue as an estimate: its border and core regions, the CV of its most excitable region."""
    fitted = method.baseline.result.tissue
    a = float(fitted.a.min())
    cv = healthy_speed(TissueSpec(healthy=Material(a=a, D=float(diffusivity_from_excitability(a)))), diffusivity)
    abnormal = np.isin(fitted.label, ABNORMAL_LABELS).astype(np.float32)
    return TissueEstimate(abnormal, np.zeros_like(abnormal), np.array([cv]), mesh)


def run_folds(
    store: str, methods: list[Method], fs_bo: Method | None, fs_bo_folds: int, folds: int, seed: int = 0
) -> list[dict]:
    """One row per (subject, fold, method) and one per (subject, fold) for the ceiling (module docstring)."""
    view = StoreView(store)
    diffusivity = float(read_solver_settings(store)["diffusivity"])
    hierarchy_of = {}
    rows = []
    for si, subject in enumerate(view.subjects):
        truth = subject_truth(view, subject)
        mesh_id = view.mesh_of[subject]
        mesh = view.mesh(mesh_id)
        if mesh_id not in hierarchy_of:
            model = methods[0].model
            cfg = model.config
            hierarchy_of[mesh_id] = view.hierarchy(mesh_id, cfg.levels, cfg.coarsest, cfg.working_nodes)
        hier = hierarchy_of[mesh_id]
        n_sites = len(view.sites(mesh_id))
        base = {"subject": subject, "heart": truth.heart, "family": truth.family}
        for left in range(n_sites if folds <= 0 else min(folds, n_sites)):
            ctx = [r for r in range(n_sites) if r != left]
            ep, noisy = observe_fold(store, subject, ctx, left, OBSERVATION, np.random.default_rng([seed, si, left]))
            seen = ep.observed.numpy()
            true_u = ep.target_u[0].numpy()
            true_act = activation_times(true_u, view.times)
            fold = {**base, "left_out": left}
            rows.append({**fold, "method": "ceiling", "cc": spatial_cc(true_u[:, seen], noisy[:, seen])})
            chosen = [*methods, *([fs_bo] if fs_bo is not None and left < fs_bo_folds else [])]
            for m in chosen:
                t0 = time.perf_counter()
                m.fit(ep, mesh, hier)
                pred = m.predict(ep.target_sites)[0]
                row = {
                    **fold,
                    "method": m.name,
                    "cc": spatial_cc(pred[:, seen], noisy[:, seen]),
                    "activation_ms": activation_error_ms(pred, true_act, view.times)[0],
                    "seconds": time.perf_counter() - t0,
                }
                if left == 0:
                    estimate = (
                        neural_tissue(m, ep, hier, mesh) if m is not fs_bo else fs_bo_tissue(m, mesh, diffusivity)
                    )
                    if estimate is not None:
                        row |= tissue_scores(estimate, truth.abnormal, truth.cv)
                rows.append(row)
        print(f"{si + 1}/{len(view.subjects)} {subject} ({truth.family})", flush=True)
    return rows


def _mean(rows: list[dict], key: str) -> float:
    values = [r[key] for r in rows if key in r and np.isfinite(r[key])]
    return float(np.mean(values)) if values else float("nan")


def summarise(rows: list[dict]) -> dict:
    """Per (heart, family) and overall per heart: each method's means, the ceiling's CC and the share of it."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in rows:
        groups[(r["heart"], r["family"])].append(r)
        groups[(r["heart"], "all")].append(r)
    summary = {}
    for (heart, family), members in sorted(groups.items()):
        ceiling = [r for r in members if r["method"] == "ceiling"]
        entry = {"subjects": len({r["subject"] for r in ceiling}), "ceiling_cc": _mean(ceiling, "cc"), "methods": {}}
        for name in dict.fromkeys(r["method"] for r in members if r["method"] != "ceiling"):
            mine = [r for r in members if r["method"] == name]
            keys = {(r["subject"], r["left_out"]) for r in mine}
            paired = [r for r in ceiling if (r["subject"], r["left_out"]) in keys]
            entry["methods"][name] = {
                "folds": len(mine),
                "cc": _mean(mine, "cc"),
                "share": _mean(mine, "cc") / _mean(paired, "cc"),
                "activation_ms": _mean(mine, "activation_ms"),
                "tissue_dice": _mean(mine, "tissue_dice"),
                "cv_error": _mean(mine, "cv_error"),
            }
        summary[f"{heart} | {family}"] = entry
    return summary


def _cell(value: float, fmt: str, unit: str = "") -> str:
    return "-" if not np.isfinite(value) else format(value, fmt) + unit


def markdown(summary: dict, names: list[str]) -> str:
    """The accuracy table and the tissue table."""
    head = " | ".join(f"{n}: CC (share) | {n}: act. ms" for n in names)
    lines = [
        f"| heart | family | subjects | ceiling CC | {head} |",
        "|---|---|---:|---:|" + "---:|---:|" * len(names),
    ]
    tissue = [
        "\n| heart | family | " + " | ".join(f"{n}: Dice | {n}: CV error" for n in names) + " |",
        "|---|---|" + "---:|---:|" * len(names),
    ]
    for key, entry in summary.items():
        heart, family = key.split(" | ")
        cells, tcells = [], []
        for n in names:
            m = entry["methods"].get(n)
            if m is None:
                cells.append("- | -")
                tcells.append("- | -")
                continue
            cells.append(f"{m['cc']:.3f} ({100 * m['share']:.0f}%) | {_cell(m['activation_ms'], '.1f')}")
            tcells.append(f"{_cell(m['tissue_dice'], '.2f')} | {_cell(100 * m['cv_error'], '.0f', '%')}")
        lines.append(f"| {heart} | {family} | {entry['subjects']} | {entry['ceiling_cc']:.3f} | {' | '.join(cells)} |")
        tissue.append(f"| {heart} | {family} | {' | '.join(tcells)} |")
    return "\n".join(lines + tissue) + "\n"


def test_split_scores(models: dict[str, str], store: str, split_from: str) -> dict:
    """Each model on ``split_from``'s test subjects of ``store``, family by family (module docstring)."""
    view = StoreView(store)
    groups: dict[str, list[str]] = defaultdict(list)
    for subject in load_checkpoint(split_from, kind="model")["splits"]["test"]:
        tissue = tissue_spec_from_mapping(subject_attrs(store, subject)["tissue"])
        drawn = tissue.name.startswith("draw-")
        groups["drawn: " + tissue_family(tissue) if drawn else "named settings (the old four)"].append(subject)
    spec_of = {
        name: EvalSpec(subjects=tuple(subjects), context_sets=1, max_targets=8) for name, subjects in groups.items()
    }
    return {
        model: {
            g: {**evaluate([ckpt], view.store, s).overall["target"], "subjects": len(s.subjects)}
            for g, s in spec_of.items()
        }
        for model, ckpt in models.items()
    }


def test_split_markdown(scores: dict) -> str:
    names = list(scores)
    groups = list(next(iter(scores.values())))
    lines = [
        "\n| training store's test subjects | subjects | "
        + " | ".join(f"{n}: CC spatial | {n}: MSE" for n in names)
        + " |",
        "|---|---:|" + "---:|---:|" * len(names),
    ]
    for g in sorted(groups):
        cells = [f"{scores[n][g]['cc_spatial']['mean']:.3f} | {scores[n][g]['mse']['mean']:.4f}" for n in names]
        lines.append(f"| {g} | {scores[names[0]][g]['subjects']} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--store", required=True, help="the benchmark store (specs/benchmark-prior.toml)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CKPT", help="a model to score")
    parser.add_argument("--fs-bo-folds", type=int, default=0, help="FS-BO on the first N folds of each subject")
    parser.add_argument("--folds", type=int, default=0, help="only the first N folds of each subject (0: all)")
    parser.add_argument("--test-store", help="the models' training store (specs/pretrained-prior.toml)")
    parser.add_argument("--split-from", help="checkpoint whose test split of --test-store is scored")
    add_out_argument(parser, "tissue_families")
    add_publish_argument(parser, "tissue_families")
    args = parser.parse_args()
    check_publish(args.publish)
    models = dict(m.split("=", 1) for m in args.model)
    methods = []
    for name, ckpt in models.items():
        method, _, _ = load_method(ckpt)
        method.name = name
        methods.append(method)
    fs_bo = None
    if args.fs_bo_folds > 0:
        view = StoreView(args.store)
        context = MethodContext(solver=read_solver_settings(args.store), times=view.times)
        fs_bo = build_methods(("fs-bo",), context)[0]
    t0 = time.perf_counter()
    rows = run_folds(args.store, methods, fs_bo, args.fs_bo_folds, args.folds)
    names = [*models, *(["fs-bo"] if fs_bo is not None else [])]
    summary = summarise(rows)
    table = markdown(summary, names)
    result = {"summary": summary, "rows": rows, "seconds": time.perf_counter() - t0}
    if args.test_store and args.split_from:
        result["test_split"] = test_split_scores(models, args.test_store, args.split_from)
        table += test_split_markdown(result["test_split"])
    write_out(args.out, "tissue_families", table, result)
    publish_out(args.publish, "tissue_families", table)
    print(table)
    print(json.dumps({"seconds": result["seconds"]}))


if __name__ == "__main__":
    main()
