"""Benchmark: the isotropic and the fibre model on hearts that conduct along fibres, against the noise ceiling.

Both shipped models (``--iso-model``, default ``anatomies``, trained on isotropic simulations; and
``--fibre-model``, default ``anatomies-fibres``, trained on the same hearts with LDRB fibres and
``D_l / D_t = 4``) personalise and predict on the same anisotropic truth:

* unseen sampled hearts: the test split of ``--store`` (``specs/pretrained-fibres.toml``: the hearts neither
  model trained on, every tissue setting), one context set of 1-5 surface-observed simulations (noise 0.02)
  and ``--targets`` targets per subject (``learner evaluate``), scored against the noise-free simulations,
  so the ceiling is CC 1;
* every real heart of ``--real`` (``specs/realdata-fibres.toml``: the three shipped hearts with fibres, 3
  tissue settings, 8 epicardial sites) through the 247-electrode sock with noise 0.02, leaving one site out
  in turn (``learner.benchmark.real_data``), scored against the noisy sock like the noise-free truth (the
  ceiling); the share of the ceiling is the model's spatial CC over the ceiling's (the table ends with the
  fibre model's lowest).

Run::

    simgen build specs/pretrained-fibres.toml --store data/pretrained-fibres.zarr --workers 2
    simgen build specs/realdata-fibres.toml --store data/realdata-fibres.zarr
    .venv/bin/python -m bench.fibre_model --store data/pretrained-fibres.zarr --real data/realdata-fibres.zarr

``--publish`` writes the table into the block ``fibre_model`` of docs/results.md.
"""

from __future__ import annotations

import argparse

import numpy as np

from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from bench.pretrained import unseen_and_real
from learner.checkpoint import load_checkpoint
from learner.store_view import StoreView


def by_heart(real: str, folds: list[dict]) -> dict[str, list[float]]:
    """The target spatial CC of each fold, grouped by the real heart (mesh) of its subject."""
    view = StoreView(real)
    hearts: dict[str, list[float]] = {}
    for fold in folds:
        hearts.setdefault(view.mesh_of[fold["subject"]], []).append(float(fold["cc_spatial"]))
    return hearts


def model_rows(model: str, args: argparse.Namespace, test: list[str]) -> dict:
    """One model's unseen-heart metrics and its real-heart folds (with the ceiling's)."""
    unseen, real, name, seconds = unseen_and_real(model, args.store, args.real, test, args.targets, args.sites)
    return {
        "unseen": unseen.overall["target"],
        "real": by_heart(args.real, real["folds"][name]),
        "ceiling": by_heart(args.real, real["folds"]["ceiling"]),
        "seconds": round(sum(seconds), 1),
    }


def table(result: dict, models: dict[str, str]) -> list[str]:
    """Spatial CC of each model on the unseen hearts and on each real heart, with the ceiling and its share."""
    names = list(models)
    lines = [
        "| hearts | ceiling CC | " + " | ".join(f"{n} CC (share of ceiling)" for n in names) + " |",
        "|---|---:|" + "---:|" * len(names),
    ]
    cells = []
    for name in names:
        cc = result[name]["unseen"]["cc_spatial"]
        cells.append(f"{cc['mean']:.3f} +- {cc['std']:.3f} ({cc['mean']:.0%})")
    lines.append(f"| unseen sampled hearts ({len(result['test'])} subjects), surface | 1 | " + " | ".join(cells) + " |")
    for heart, ceiling in result[names[0]]["ceiling"].items():
        top = float(np.mean(ceiling))
        cells = []
        for name in names:
            cc = result[name]["real"][heart]
            cells.append(f"{np.mean(cc):.3f} +- {np.std(cc):.3f} ({np.mean(cc) / top:.0%})")
        lines.append(f"| real:{heart}, sock, {len(ceiling)} folds | {top:.3f} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iso-model", default="anatomies", help="the isotropic model (name or checkpoint)")
    parser.add_argument("--fibre-model", default="anatomies-fibres", help="the fibre model (name or checkpoint)")
    parser.add_argument("--store", required=True, help="the fibre model's training store (its test split is used)")
    parser.add_argument("--real", required=True, help="real hearts with fibres (specs/realdata-fibres.toml)")
    parser.add_argument("--targets", type=int, default=10, help="targets per context set on the unseen hearts")
    parser.add_argument("--sites", type=int, default=8, help="pacing sites of each real heart (leave one out)")
    add_out_argument(parser, "fibre_model")
    add_publish_argument(parser, "fibre_model")
    args = parser.parse_args()
    check_publish(args.publish)

    models = {"isotropic model": args.iso_model, "fibre model": args.fibre_model}
    test = list(load_checkpoint(args.fibre_model, kind="model")["splits"]["test"])
    trained_on = set(load_checkpoint(args.iso_model, kind="model")["splits"]["train"])
    if trained_on & set(test):
        parser.error(f"{args.iso_model} trained on {len(trained_on & set(test))} of the test subjects")
    result = {"test": test, "machine": machine(), **{name: model_rows(m, args, test) for name, m in models.items()}}
    lines = table(result, models)
    worst = min(
        np.mean(result["fibre model"]["real"][h]) / np.mean(c) for h, c in result["fibre model"]["ceiling"].items()
    )
    verdict = f"The fibre model's lowest share of the ceiling on a real heart: {worst:.0%}."
    text = "\n".join(
        [
            f"Models: isotropic `{args.iso_model}`, fibre `{args.fibre_model}`; truth with LDRB fibres and "
            f"D_l / D_t = 4; {sum(result[n]['seconds'] for n in models):.0f} s.",
            "",
            *lines,
            "",
            verdict,
        ]
    )
    print(f"{machine_line()}\n\n{text}")
    write_out(args.out, "fibre_model", text + "\n", result)
    publish_out(args.publish, "fibre_model", text)


if __name__ == "__main__":
    main()
