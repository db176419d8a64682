"""Accuracy on unseen hearts against the number of training anatomies.

Trains one model per count ``n`` of ``--counts`` on only ``n`` of the training anatomies of
``--config`` (``data.split.train_count``: nested subsets, the same validation and test hearts), each
for the same number of optimiser steps (``--steps`` episodes: ``ceil(steps / subjects)`` epochs,
learning rate halved at 40 % and 80 % of them, validation five times), then evaluates each on

* the unseen sampled hearts (the test split: every tissue setting of each), and
* the real heart of ``--real`` through the 247-electrode sock with noise 0.02 (leave one site out),

as :mod:`bench.unseen_anatomies` does. ``--pns N`` also trains PNS (no context) on ``N`` anatomies
with the same budget, the baseline the curve's metaPNS points are compared with. A run resumes from
its ``last.pt``, so the command can be repeated after an interruption; ``--only train`` with one count
lets two models train side by side, ``--only report`` evaluates what is there.

Run::

    .venv/bin/python -m bench.anatomy_curve --config specs/train-anatomies.toml --real data/realdata.zarr \\
        --counts 2 8 32 --pns 32 --steps 1280 --runs runs/anatomy-curve --out report/anatomy-curve

Writes ``anatomy_curve.json``, ``anatomy_curve.md`` and ``anatomy_curve.png`` to ``--out``;
``--publish`` writes the table into the block ``anatomy_curve`` of docs/results.md (the figure is
``docs/anatomy_curve.png``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

from bench.common import add_publish_argument, check_publish, publish_out, write_out
from bench.unseen_anatomies import real_heart, unseen_procedural
from learner.checkpoint import load_checkpoint
from learner.config import LearnerConfig, load_config
from learner.data.split import SplitSpec, split_subjects
from learner.store_view import StoreView
from learner.train.trainer import train


def run_config(base: LearnerConfig, runs: Path, count: int, kind: str, steps: int) -> LearnerConfig:
    """``base`` trained on ``count`` anatomies for ``steps`` episodes, in ``runs/<kind>-<count>``.

    PNS reads no context, so it gets no capture gate (nor the gate's loss) whatever ``base`` sets."""
    split = dataclasses.replace(base.data.split, train_count=count)
    subjects = _train_subjects(base, split)
    epochs = math.ceil(steps / subjects)
    gated = kind == "metapns"
    model = dataclasses.replace(base.model, kind=kind)
    if not gated:
        model = dataclasses.replace(model, capture_gate=False, capture_evidence=False)
    return dataclasses.replace(
        base,
        out=str(runs / f"{kind}-{count}"),
        data=dataclasses.replace(base.data, split=split),
        model=model,
        train=dataclasses.replace(
            base.train,
            gate_loss=base.train.gate_loss if gated else 0.0,
            epochs=epochs,
            lr_halve_every=max(1, round(0.4 * epochs)),
            validate_every=max(1, epochs // 5),
        ),
    )


def _train_subjects(config: LearnerConfig, split: SplitSpec) -> int:
    view = StoreView(config.data.store)
    return len(split_subjects(view.subjects, view.mesh_of, split)["train"])


def curve_figure(rows: list[dict], path: Path) -> None:
    """Target CC (spatial) and MSE on the unseen hearts against the number of training anatomies."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    meta = sorted((r for r in rows if r["kind"] == "metapns"), key=lambda r: r["count"])
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, metric, label in zip(axes, ("cc_spatial", "mse"), ("target CC (spatial)", "target MSE"), strict=True):
        for test, style in (("unseen", "o-"), ("real", "s--")):
            name = "unseen sampled hearts" if test == "unseen" else "real heart via sock"
            ys = [r[test]["target"][metric]["mean"] for r in meta]
            ax.plot([r["count"] for r in meta], ys, style, label=f"metaPNS, {name}")
            for r in rows:
                if r["kind"] == "pns":
                    ax.plot([r["count"]], [r[test]["target"][metric]["mean"]], "x", ms=9, label=f"PNS, {name}")
        ax.set_xscale("log", base=2)
        ax.set_xticks([r["count"] for r in meta], [str(r["count"]) for r in meta])
        ax.set_xlabel("training anatomies")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(rows: list[dict], steps: int, n_test: int) -> str:
    """One row per model."""
    lines = [
        f"| model | training anatomies | epochs ({steps} steps) | best val MSE | unseen hearts ({n_test} subjects): "
        "target MSE | CC spatial | DC | real heart via sock: target MSE | CC spatial |",
        "|---|---:|---:|---:|---:|---|---:|---:|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["kind"], r["count"])):
        a, b = r["unseen"]["target"], r["real"]["target"]
        lines.append(
            f"| {'metaPNS' if r['kind'] == 'metapns' else 'PNS'} | {r['count']} | {r['epochs']} "
            f"| {r['best_validation']:.4f} | {a['mse']['mean']:.4f} "
            f"| {a['cc_spatial']['mean']:.3f} +- {a['cc_spatial']['std']:.3f} | {a['dc']['mean']:.3f} "
            f"| {b['mse']['mean']:.4f} | {b['cc_spatial']['mean']:.3f} +- {b['cc_spatial']['std']:.3f} |"
        )
    if rows and "ceiling" in rows[0]["real"]:
        c = rows[0]["real"]["ceiling"]["target"]
        lines.append(
            f"\nReal heart: the noise-free truth scores target MSE {c['mse']['mean']:.4f}, "
            f"CC spatial {c['cc_spatial']['mean']:.3f} +- {c['cc_spatial']['std']:.3f} (the ceiling)."
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", type=Path, default=Path("specs/train-anatomies.toml"))
    parser.add_argument("--real", required=True, help="real-heart store (specs/realdata.toml)")
    parser.add_argument("--counts", type=int, nargs="*", default=[2, 8, 32])
    parser.add_argument("--pns", type=int, nargs="*", default=[], help="also train PNS on these counts")
    parser.add_argument("--steps", type=int, default=1280, help="training episodes per model")
    parser.add_argument("--sets", type=int, default=1, help="context sets per unseen subject")
    parser.add_argument("--targets", type=int, default=10, help="targets per context set")
    parser.add_argument("--sites", type=int, default=8, help="pacing sites of the real heart (leave one out)")
    parser.add_argument("--runs", type=Path, default=Path("runs/anatomy-curve"))
    parser.add_argument("--out", type=Path, default=Path("report/anatomy-curve"))
    parser.add_argument("--only", choices=("train", "report"), help="train (no evaluation) or evaluate only")
    add_publish_argument(parser, "anatomy_curve")
    args = parser.parse_args()
    check_publish(args.publish)

    base = load_config(args.config)
    models = [(n, "metapns") for n in args.counts] + [(n, "pns") for n in args.pns]
    configs = {m: run_config(base, args.runs.resolve(), m[0], m[1], args.steps) for m in models}
    if args.only != "report":
        for (count, kind), cfg in configs.items():
            print(f"{kind} on {count} anatomies: {cfg.train.epochs} epochs -> {cfg.out}", flush=True)
            train(cfg)
    if args.only == "train":
        return
    rows = []
    for (count, kind), cfg in configs.items():
        checkpoint = str(Path(cfg.out) / "best.pt")
        ckpt = load_checkpoint(checkpoint, kind="model")
        start = time.perf_counter()
        row = {
            "count": count,
            "kind": kind,
            "epochs": cfg.train.epochs,
            "best_validation": float(ckpt["best_validation"]),
            "unseen": unseen_procedural(checkpoint, cfg.data.store, ckpt["splits"]["test"], args.sets, args.targets),
            "real": real_heart(checkpoint, args.real, args.sites),
        }
        row["seconds"] = time.perf_counter() - start
        rows.append(row)
        print(kind, count, json.dumps({k: row["unseen"]["target"][k]["mean"] for k in ("mse", "cc_spatial", "dc")}))
    n_test = len(ckpt["splits"]["test"])
    table = markdown(rows, args.steps, n_test)
    write_out(args.out, "anatomy_curve", table, {"steps": args.steps, "models": rows})
    curve_figure(rows, args.out / "anatomy_curve.png")
    publish_out(args.publish, "anatomy_curve", table)
    print(table)


if __name__ == "__main__":
    main()
