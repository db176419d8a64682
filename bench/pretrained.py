"""The shipped model's card metrics: unseen sampled hearts, the real heart through the sock, the mean predictor.

Evaluates a shipped model (``--model``, a name of ``learner models`` or a checkpoint) on

* (a) the test hearts of ``--store`` (the model's training store: ``specs/pretrained.toml`` for ``anatomies``):
  the model's own test split (whole sampled anatomies held out of training, every tissue setting of each),
  one context set of 1-5 surface-observed simulations (noise 0.02, as in training) and ``--targets`` targets
  per subject (``learner evaluate``);
* (b) the real heart of ``--real`` (``specs/realdata.toml``: the shipped MRI biventricle ``real:tof-biv``,
  3 tissue settings, 8 epicardial pacing sites) through the 247-electrode sock with noise 0.02, leaving one
  site out in turn (``learner.benchmark.real_data``), beside the noise-free truth (the metric's ceiling);
* (c) the mean predictor on (a)'s subjects: each frame's mean potential over every training simulation and
  node (``StoreView.frame_means`` of the training split), the predictor that ignores all inputs.

Writes ``pretrained.md`` and ``pretrained.json`` to ``--out``; the table is the model card's
(``learner/pretrained/<name>/README.md``).

Run::

    simgen build specs/pretrained.toml --store data/pretrained.zarr --workers 2
    simgen build specs/realdata.toml --store data/realdata.zarr
    .venv/bin/python -m bench.pretrained --store data/pretrained.zarr --real data/realdata.zarr
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import add_out_argument, machine_line, write_out
from learner.benchmark import BenchmarkConfig, RealDataSpec, real_data, real_data_setting
from learner.checkpoint import load_checkpoint
from learner.evaluate import EvalReport, EvalSetting, EvalSpec, evaluate, load_method
from learner.metrics import mse
from learner.store_view import StoreView
from shared.reader import read_u


def mean_predictor(store: str, train: list[str], test: list[str]) -> float:
    """Target MSE of the training frame means on every simulation of ``test``, averaged over subjects."""
    view = StoreView(store)
    means = view.frame_means([s for s in train if s in view.mesh_of])
    errors = []
    for subject in test:
        u = read_u(store, subject)
        errors.append(mse(np.broadcast_to(means[None, :, None], u.shape), u))
    return float(np.mean(errors))


def unseen_and_real(
    model: str, store: str, real: str, test: list[str], targets: int, sites: int
) -> tuple[EvalReport, dict, str, tuple[float, float]]:
    """``model`` on the ``test`` subjects of ``store`` (one context set each, ``targets`` targets) and on every
    leave-one-site-out fold of the real hearts of ``real`` (``sites`` each) through the sock: the evaluation
    report, :func:`~learner.benchmark.real_data`'s result, the model's method name there, and the seconds of
    each."""
    start = time.perf_counter()
    unseen = evaluate(model, store, EvalSpec(subjects=tuple(test), context_sets=1, max_targets=targets))
    unseen_s = time.perf_counter() - start
    method, config, _ = load_method(model)
    start = time.perf_counter()
    real_cfg = BenchmarkConfig(real_data=RealDataSpec(store=real, sites=sites))
    folds = real_data([method], real_data_setting(real_cfg, EvalSetting.of(config)), real_cfg)
    return unseen, folds, method.name, (unseen_s, time.perf_counter() - start)


def card_metrics(result: dict) -> dict:
    """The card's figures as config.json records them: mean and std of each metric per test set."""

    def means(stats: dict) -> dict:
        return {name: {"mean": round(v["mean"], 5), "std": round(v["std"], 5)} for name, v in stats.items()}

    return {
        "unseen_sampled_hearts": {"subjects": len(result["test"]), **means(result["unseen"]["target"])},
        "mean_predictor_mse": round(result["mean_predictor_mse"], 5),
        "real_heart_sock": {"subjects": result["real"]["subjects"], **means(result["real"]["target"])},
        "real_heart_ceiling": means(result["real"]["ceiling"]),
    }


def record_card(model: str, result: dict) -> Path:
    """Write the model's version (the package's), today's date and :func:`card_metrics` into its config.json."""
    from datetime import date
    from importlib.metadata import version

    from learner.pretrained import CONFIG, info

    path = info(model).folder / CONFIG
    document = json.loads(path.read_text())
    document["card"] = {
        "version": version("metapns"),
        "date": date.today().isoformat(),
        "metrics": card_metrics(result),
        "measured_on": result["machine"],
        "command": " ".join(["python -m bench.pretrained", shlex.join(sys.argv[1:])]),
    }
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path


def _cell(stats: dict) -> str:
    return (
        f"{stats['mean']:.4f} +- {stats['std']:.4f}"
        if stats["mean"] < 0.1
        else f"{stats['mean']:.3f} +- {stats['std']:.3f}"
    )


def markdown(result: dict) -> str:
    """The card's table."""
    a, b, c = result["unseen"]["target"], result["real"]["target"], result["real"]["ceiling"]
    lines = [
        "| test set | target MSE | target CC spatial | target CC temporal | target DC |",
        "|---|---|---|---|---|",
        f"| unseen sampled hearts ({result['unseen_meshes']} hearts x {len(result['tissues'])} tissue settings, "
        f"{len(result['test'])} subjects), surface "
        f"| {_cell(a['mse'])} | {_cell(a['cc_spatial'])} | {_cell(a['cc_temporal'])} | {_cell(a['dc'])} |",
        f"| mean predictor on the same subjects | {result['mean_predictor_mse']:.4f} | - | - | - |",
        f"| real heart ({', '.join(result['real']['subjects'])}), {result['real']['electrodes']} electrodes, "
        f"leave one of {result['real_sites']} sites out | {_cell(b['mse'])} | {_cell(b['cc_spatial'])} "
        f"| {_cell(b['cc_temporal'])} | - |",
        f"| real heart: noise-free truth (ceiling) | {_cell(c['mse'])} | {_cell(c['cc_spatial'])} "
        f"| {_cell(c['cc_temporal'])} | - |",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="anatomies", help="shipped model name or checkpoint (default anatomies)")
    parser.add_argument("--store", required=True, help="anatomy-diverse store (specs/anatomies.toml)")
    parser.add_argument("--real", required=True, help="real-heart store (specs/realdata.toml)")
    parser.add_argument("--targets", type=int, default=10, help="targets per context set on the unseen hearts")
    parser.add_argument("--sites", type=int, default=8, help="pacing sites of the real heart (leave one out)")
    parser.add_argument(
        "--tissues",
        help="comma-separated tissue settings: only the test subjects of these (e.g. the four a model was trained on)",
    )
    parser.add_argument(
        "--record-card",
        action="store_true",
        help="also record the metrics, version and date in the shipped model's config.json ('card')",
    )
    add_out_argument(parser, "pretrained", Path("report/pretrained"))
    args = parser.parse_args()

    splits = load_checkpoint(args.model, kind="model")["splits"]
    view = StoreView(args.store)
    test = [s for s in splits["test"] if not args.tissues or view.tissue_of[s] in args.tissues.split(",")]
    if not test:
        parser.error(f"no test subject of {args.model} in {args.store} has a tissue of {args.tissues}")
    unseen, real, name, (unseen_s, real_s) = unseen_and_real(
        args.model, args.store, args.real, test, args.targets, args.sites
    )
    result = {
        "model": args.model,
        "test": test,
        "tissues": sorted({view.tissue_of[s] for s in test}),
        "unseen_meshes": len({view.mesh_of[s] for s in test}),
        "unseen": unseen.overall,
        "mean_predictor_mse": mean_predictor(args.store, list(splits["train"]), test),
        "real": {
            "subjects": real["subjects"],
            "electrodes": real["electrodes"],
            "noise_std": real["noise_std"],
            **real["methods"][name],
            "ceiling": real["ceiling"]["target"],
            "folds": real["folds"],
        },
        "real_sites": args.sites,
        "seconds": {"unseen": unseen_s, "real": real_s},
        "machine": machine_line(),
    }
    table = markdown(result)
    write_out(args.out, "pretrained", table, result)
    if args.record_card:
        print(f"recorded the card's metrics in {record_card(args.model, result)}")
    print(table)
    print(f"unseen hearts {unseen_s:.0f} s, real heart {real_s:.0f} s on {result['machine']}")


if __name__ == "__main__":
    main()
