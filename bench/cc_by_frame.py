"""Where the spatial correlation is lost: target CC frame by frame, healthy against scarred hearts.

``cc_spatial`` is a Pearson correlation over the nodes of each frame, averaged over the frames whose
maps are not exactly constant. Once a heart is fully excited (and again once it has recovered) its map
is nearly uniform: a spatial spread of a few thousandths of the range of ``u``. The correlation of such
a frame measures only that residue, whatever the prediction's error, and counts as much as a frame
with a wavefront. A scar keeps its region low during the plateau, so scarred hearts have fewer such
frames than healthy ones.

For each ``--model NAME=CHECKPOINT`` the script predicts the targets of the test subjects of
``--store`` (the checkpoint's split) exactly as ``learner evaluate --sets 1 --max-targets 10`` does
(the same context sets and targets), and splits every target frame by its truth's spatial standard
deviation (below ``--flat``, default 0.01: a nearly uniform frame). It writes

* ``cc_by_frame.md``: per model and group (healthy, scarred) the target CC, the share of nearly uniform
  frames and the mean CC of either kind of frame;
* ``cc_by_frame.png``: the mean target CC of each frame index, healthy and scarred subjects apart.

``--publish`` writes the table into the block ``cc_by_frame`` of docs/results.md (the figure is
``docs/cc_by_frame.png``).

Run::

    .venv/bin/python -m bench.cc_by_frame --store data/anatomies.zarr \\
        --model anatomies=runs/anatomies-metapns/best.pt --out report/cc-by-frame
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from torch import Tensor

from bench.common import add_out_argument, add_publish_argument, check_publish, publish_out, write_out
from learner.checkpoint import load_checkpoint
from learner.data.episodes import Episode
from learner.evaluate import EvalSetting, EvalSpec, Method, NeuralMethod, evaluate_methods, load_model
from learner.metrics import frame_cc
from learner.store_view import StoreView
from shared.mesh import Mesh
from shared.reader import subject_attrs


class Recording(Method):
    """A method that keeps each target's per-frame CC and truth spread as the evaluation runs it."""

    def __init__(self, inner: Method) -> None:
        self.inner, self.name = inner, inner.name
        self.frames: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._episode: Episode | None = None

    def fit(self, episode: Episode, mesh: Mesh, hierarchy) -> dict[str, float]:
        self._episode = episode
        return self.inner.fit(episode, mesh, hierarchy)

    def predict(self, sites: Tensor) -> np.ndarray:
        pred, ep = self.inner.predict(sites), self._episode
        k = len(ep.context_sites)
        for p, t in zip(pred[k:], ep.target_u.numpy(), strict=True):
            self.frames.setdefault(ep.subject_id, []).append((frame_cc(p, t), t.std(axis=-1)))
        return pred


def record(checkpoint: str, store: str, targets: int) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Per test subject, ``(frame CC, truth spatial std)`` of every target, as ``learner evaluate`` draws them."""
    model, config, _ = load_model(checkpoint)
    test = list(load_checkpoint(checkpoint, kind="model")["splits"]["test"])
    view = StoreView(store, cache_dir=Path(checkpoint).parent / "hierarchies")
    method = Recording(NeuralMethod(model, config.model.kind))
    spec = EvalSpec(context_sets=1, max_targets=targets)
    evaluate_methods([method], view, test, spec, EvalSetting.of(config))
    return method.frames


def summarise(frames: list[tuple[np.ndarray, np.ndarray]], flat: float) -> dict[str, float]:
    """Target CC (mean over sequences of their frame mean), share of flat frames, CC of flat and other frames."""
    cc = np.stack([c for c, _ in frames])
    spread = np.stack([s for _, s in frames])
    defined = np.isfinite(cc)
    is_flat = (spread < flat) & defined
    return {
        "sequences": len(frames),
        "cc": float(np.mean([np.nanmean(c) for c in cc])),
        "flat_share": float(is_flat.sum() / defined.sum()),
        "cc_flat": float(cc[is_flat].mean()) if is_flat.any() else float("nan"),
        "cc_other": float(cc[defined & ~is_flat].mean()),
        "cc_by_frame": np.nanmean(cc, axis=0).tolist(),
    }


def figure(results: dict, path: Path) -> None:
    """Mean target CC of each frame index per model and group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6))
    for name, groups in results.items():
        for group, s in groups.items():
            ax.plot(s["cc_by_frame"], label=f"{name}, {group}")
    ax.set_xlabel("frame")
    ax.set_ylabel("target CC (spatial), mean over targets")
    ax.set_ylim(-1, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--store", required=True)
    parser.add_argument("--model", action="append", required=True, help="NAME=CHECKPOINT (repeatable)")
    parser.add_argument("--targets", type=int, default=10, help="targets per context set")
    parser.add_argument("--flat", type=float, default=0.01, help="truth spatial std below which a frame is flat")
    add_out_argument(parser, "cc_by_frame", Path("report/cc-by-frame"))
    add_publish_argument(parser, "cc_by_frame")
    args = parser.parse_args()
    check_publish(args.publish)

    results: dict[str, dict] = {}
    for item in args.model:
        name, _, checkpoint = item.partition("=")
        per_subject = record(checkpoint, args.store, args.targets)
        healthy = {s for s in per_subject if not subject_attrs(args.store, s)["tissue"]["scars"]}
        groups = {
            "healthy": [f for s in healthy for f in per_subject[s]],
            "scarred": [f for s, fs in per_subject.items() if s not in healthy for f in fs],
            "all": [f for fs in per_subject.values() for f in fs],
        }
        results[name] = {g: summarise(frames, args.flat) for g, frames in groups.items() if frames}
    lines = [
        f"| model | subjects | targets | target CC | truth spatial std < {args.flat} | CC there | elsewhere |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, groups in results.items():
        for group, s in groups.items():
            lines.append(
                f"| {name} | {group} | {s['sequences']} | {s['cc']:.3f} | {100 * s['flat_share']:.0f} % "
                f"| {s['cc_flat']:.3f} | {s['cc_other']:.3f} |"
            )
    table = "\n".join(lines) + "\n"
    write_out(args.out, "cc_by_frame", table, results)
    publish_out(args.publish, "cc_by_frame", table)
    figure({n: {g: s for g, s in gs.items() if g != "all"} for n, gs in results.items()}, args.out / "cc_by_frame.png")
    print(table)


if __name__ == "__main__":
    main()
