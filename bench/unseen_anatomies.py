"""Surrogates on hearts they never saw: unseen sampled anatomies and a real heart through the sock.

Evaluates each ``--model NAME=CHECKPOINT`` on

* (a) the test anatomies of ``--store`` (the anatomy split of ``--split-from``'s checkpoint: whole
  sampled hearts held out of training, every tissue setting of each), surface-observed context sets
  of 1-5 simulations, target metrics as ``learner evaluate`` computes them;
* (b) the real heart of ``--real`` (``specs/realdata.toml``: a shipped MRI biventricle), observed
  through the 247-electrode epicardial sock with noise 0.02, leaving one pacing site out in turn
  (``learner.benchmark.real_data``).

``--refine-steps 0 30`` evaluates each model twice: with ``c`` the context encoder's mean, and with
``c`` refined on each context set in 30 gradient steps (``learner.refine``); ``--refine-real-only``
scores the refined runs on the real heart alone. ``--model NAME=CKPT1+CKPT2`` evaluates an ensemble
(``learner.evaluate.EnsembleMethod``: each member personalised on the same context, predictions averaged).

The real heart's table is also written fold by fold, beside the noise-free truth's CC (the ceiling).

Models trained on other stores (e.g. the 3 fixed meshes of ``specs/default.toml``) are evaluated on
the same subjects, so the table compares them side by side. Writes ``unseen_anatomies.json`` and
``unseen_anatomies.md`` to ``--out``; ``--publish [SECTION]`` writes the tables into the block SECTION
(default ``unseen_anatomies``; ``unseen_anatomies.refined`` for the refined runs) of docs/results.md.

Run::

    .venv/bin/python -m bench.unseen_anatomies --store data/anatomies.zarr --real data/realdata.zarr \\
        --split-from runs/anatomies-metapns/best.pt \\
        --model anatomies=runs/anatomies-metapns/best.pt --model fixed-meshes=runs/seed1/best.pt
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench.common import add_out_argument, add_publish_argument, check_publish, publish_out, write_out
from learner.benchmark import BenchmarkConfig, RealDataSpec, real_data, real_data_setting
from learner.checkpoint import load_checkpoint
from learner.evaluate import EvalSetting, EvalSpec, evaluate, load_method
from learner.refine import Refinement
from learner.store_view import StoreView


def unseen_procedural(
    checkpoints: list[str], store: str, subjects: list[str], sets: int, targets: int, refine: Refinement = Refinement()
) -> dict:
    """Target and context metrics (mean, std) on ``subjects`` of ``store``; several checkpoints: their ensemble."""
    spec = EvalSpec(subjects=tuple(subjects), context_sets=sets, max_targets=targets, refine=refine)
    report = evaluate(checkpoints, store, spec)
    return {role: report.overall[role] for role in ("context", "target")}


def real_heart(
    checkpoints: list[str], store: str, sites: int, folds: int = 0, refine: Refinement = Refinement()
) -> dict:
    """Leave-one-site-out metrics at the sock's electrodes (noise 0.02); ``folds > 0``: the first of each subject."""
    method, config, _ = load_method(checkpoints, refine=refine)
    cfg = BenchmarkConfig(real_data=RealDataSpec(store=store, sites=sites))
    result = real_data([method], real_data_setting(cfg, EvalSetting.of(config)), cfg, folds)
    result["folds"]["model"] = result["folds"].pop(method.name)
    return {**result, **result.pop("methods")[method.name]}


def _cells(a: dict | None, b: dict) -> str:
    """Table cells of unseen-heart metrics ``a`` (MSE, CC, DC; None: not scored) and real-heart metrics ``b``."""
    unseen = (
        "- | - | -"
        if a is None
        else f"{a['mse']['mean']:.4f} | {a['cc_spatial']['mean']:.3f} +- {a['cc_spatial']['std']:.3f} "
        f"| {a['dc']['mean']:.3f}"
    )
    return f"{unseen} | {b['mse']['mean']:.4f} | {b['cc_spatial']['mean']:.3f} +- {b['cc_spatial']['std']:.3f}"


def markdown(results: dict, n_test: int, n_test_meshes: int, real: dict) -> str:
    """The side-by-side table."""
    lines = [
        f"| model | unseen anatomies ({n_test_meshes} hearts, {n_test} subjects): target MSE | CC spatial | DC "
        "| real heart via sock: target MSE | CC spatial | CC temporal |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        a, b = r["unseen"] and r["unseen"]["target"], r["real"]["target"]
        lines.append(f"| {name} | {_cells(a, b)} | {b['cc_temporal']['mean']:.3f} |")
    ceiling = real["ceiling"]["target"]
    lines.append(
        f"\nReal heart: {', '.join(real['subjects'])}, {real['electrodes']} electrodes, noise {real['noise_std']}; "
        f"the noise-free truth scores target MSE {ceiling['mse']['mean']:.4f}, CC spatial "
        f"{ceiling['cc_spatial']['mean']:.3f} +- {ceiling['cc_spatial']['std']:.3f} (the ceiling)."
    )
    return "\n".join(lines) + "\n"


def subset_markdown(results: dict, n: int) -> str:
    """The models on the baselines' subsets: the first ``n`` unseen subjects, the real heart's first folds."""
    lines = [
        f"\n| model | first {n} unseen subjects: target MSE | CC spatial | DC "
        "| real heart, first fold of each subject: target MSE | CC spatial |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        unseen = r["unseen_subset"] and r["unseen_subset"]["target"]
        lines.append(f"| {name} | {_cells(unseen, r['real_subset']['target'])} |")
    return "\n".join(lines) + "\n"


def fold_markdown(results: dict) -> str:
    """The real heart fold by fold: target CC spatial and MSE of each model, and the ceiling's CC."""
    per_model = [r["real"]["folds"]["model"] for r in results.values()]
    lines = [
        "\n| real heart: subject | left-out site | ceiling CC | "
        + " | ".join(f"{n}: CC | MSE" for n in results)
        + " |",
        "|---|---:|---:|" + "---:|---:|" * len(results),
    ]
    ceilings = next(iter(results.values()))["real"]["folds"]["ceiling"]  # the same folds for every model
    for i, ceiling in enumerate(ceilings):
        cells = [f"{folds[i]['cc_spatial']:.3f} | {folds[i]['mse']:.4f}" for folds in per_model]
        lines.append(
            f"| {ceiling['subject']} | {ceiling['left_out']} | {ceiling['cc_spatial']:.3f} | {' | '.join(cells)} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--store", required=True, help="anatomy-diverse store (specs/anatomies.toml)")
    parser.add_argument("--real", required=True, help="real-heart store (specs/realdata.toml)")
    parser.add_argument("--split-from", required=True, help="checkpoint whose test split names the unseen hearts")
    parser.add_argument(
        "--model",
        action="append",
        required=True,
        help="NAME=CHECKPOINT (repeatable); NAME=CKPT1+CKPT2 averages the predictions of an ensemble",
    )
    parser.add_argument("--sets", type=int, default=1, help="context sets per test subject")
    parser.add_argument("--targets", type=int, default=20, help="targets per context set")
    parser.add_argument("--sites", type=int, default=8, help="pacing sites of the real heart (leave one out)")
    parser.add_argument(
        "--baseline-subjects",
        type=int,
        default=0,
        help="also score the first N unseen subjects and the first fold of each real one, the subsets and draws "
        "on which `learner benchmark specs/benchmark-anatomies.toml` runs the BO baselines",
    )
    parser.add_argument(
        "--refine-steps",
        type=int,
        nargs="+",
        default=[0],
        help="evaluate each model with c refined on each context set for each of these step counts "
        "(learner.refine; 0: the encoder's mean)",
    )
    parser.add_argument(
        "--refine-real-only",
        action="store_true",
        help="score refined runs on the real heart only (refining on the 40 unseen subjects takes about 17 "
        "minutes per model on one core of the 2-core VM)",
    )
    add_out_argument(parser, "unseen_anatomies", Path("report/unseen-anatomies"))
    add_publish_argument(parser, "unseen_anatomies")
    args = parser.parse_args()
    check_publish(args.publish)

    splits = load_checkpoint(args.split_from, kind="model")["splits"]
    test = splits["test"]
    n_meshes = len({StoreView(args.store).mesh_of[s] for s in test})
    results, real = {}, {}
    runs = [(item.partition("="), steps) for item in args.model for steps in args.refine_steps]
    for (model, _, paths), steps in runs:
        name, refine = (f"{model}, refined {steps}" if steps else model), Refinement(steps=steps)
        checkpoints = paths.split("+")
        unseen = not (steps and args.refine_real_only)
        start = time.perf_counter()
        real = real_heart(checkpoints, args.real, args.sites, refine=refine)
        results[name] = {
            "checkpoints": checkpoints,
            "refine_steps": steps,
            "unseen": unseen_procedural(checkpoints, args.store, test, args.sets, args.targets, refine)
            if unseen
            else None,
            "real": real,
            "seconds": time.perf_counter() - start,
        }
        if args.baseline_subjects:
            subset = test[: args.baseline_subjects]
            results[name]["unseen_subset"] = (
                unseen_procedural(checkpoints, args.store, subset, 1, args.targets, refine) if unseen else None
            )
            results[name]["real_subset"] = real_heart(checkpoints, args.real, args.sites, folds=1, refine=refine)
        print(name, json.dumps({k: real["target"][k]["mean"] for k in ("mse", "cc_spatial")}), flush=True)
    table = markdown(results, len(test), n_meshes, real) + fold_markdown(results)
    if args.baseline_subjects:
        table += subset_markdown(results, args.baseline_subjects)
    write_out(args.out, "unseen_anatomies", table, {"test": test, **results})
    publish_out(args.publish, "unseen_anatomies", table)
    print(table)


if __name__ == "__main__":
    main()
