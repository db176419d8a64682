"""Benchmark: personalising from activation-time maps against personalising from the potentials they came from.

For every fold, a shipped model (``--model``, default ``anatomies``) is
personalised twice on the same context recordings of the same nodes: once on
the potential sequences (Gaussian noise 0.02 on ``u``, as in training) and once
on the activation-time maps of the same simulations (the noise-free first
crossing of ``u = 0.5`` plus Gaussian noise of ``--noise-ms`` ms, +inf where a
recorded node never activates), which the model reads through its
action-potential template (:mod:`learner.activation_maps`). Both predict the
same unrecorded sites; the table gives the spatial CC and the activation-time
error of each, and their difference (maps minus potentials). A model with a
maps encoder reads a map up to each node's upstroke; its table also gives the
CC from the same maps read at every frame by its context encoder (the reading
of a model without one).

* Unseen hearts: the model's test split of ``--store`` (whole sampled anatomies
  never trained on, every tissue setting), one context set of ``--context``
  random sites per subject and ``--targets`` other sites.
* Real heart: ``--real`` (``specs/realdata.toml``: ``real:tof-biv``, 3 tissue
  settings, 8 pacing sites), each site left out in turn, the others that start
  a wave as context.

Each through ``--observe`` node sets (default the 247-electrode sock, the whole
surface and the endocardium: what an electroanatomical map covers), and each
row also split into healthy and scarred subjects.

Run::

    .venv/bin/python -m bench.activation_maps --store data/pretrained.zarr --real data/realdata.zarr --out report/bench

``--publish`` writes the table into the block ``activation_maps`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace

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
from learner.activation_maps import ApTemplate
from learner.checkpoint import load_checkpoint
from learner.data.episodes import load_episode
from learner.metrics import activation_error_ms, spatial_cc
from learner.observations import Observations
from learner.personalized import NoWaveWarning, personalize
from learner.store_view import StoreView
from shared.capture import mapped_activation, started_wave
from shared.reader import read_activation
from shared.units import MS_PER_TIME_UNIT

NOISE_U = 0.02


def activation_map(u: np.ndarray, activation: np.ndarray, observed: np.ndarray, noise_ms: float, rng) -> np.ndarray:
    """Recorded activation times (K, N) in model time units: at ``observed`` nodes the activation times of
    simulations ``u`` (K, T, N) as a mapping system records them (:func:`~shared.capture.mapped_activation`)
    plus noise, NaN elsewhere."""
    mapped = mapped_activation(activation, u.max(axis=1), noise_ms / MS_PER_TIME_UNIT, rng)
    return np.where(observed[None, :], mapped, np.nan)


def fold(model: str, store: str, subject: str, context: list[int], targets: list[int], observe: str, args, seed):
    """Spatial CC and activation error (ms) of each target, from potentials and from activation maps (and, with
    ``args.every_frame`` the model's template, from the maps read at every frame by the context encoder)."""
    rng = np.random.default_rng(seed)
    ep = load_episode(store, subject, context, targets, observe, NOISE_U, rng)
    view = StoreView(store)
    mesh = view.mesh(view.mesh_of[subject])
    observed = ep.observed.numpy()
    sites, times = ep.context_sites.numpy(), ep.times.numpy()
    act = activation_map(ep.context_u.numpy(), read_activation(store, subject, context), observed, args.noise_ms, rng)
    truth = ep.target_u.numpy()
    true_act = read_activation(store, subject, targets)
    maps = Observations(mesh, sites, None, observed, times, subject, activation=act)
    routes = [("potentials", Observations(mesh, sites, ep.context_obs.numpy(), observed, times, subject))]
    routes.append(("activation", maps))
    if args.every_frame is not None:
        routes.append(("every_frame", replace(maps.at_frames(times, lambda: args.every_frame), recorded=None)))
    out = {}
    for route, obs in routes:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NoWaveWarning)
            heart = personalize(model, obs, device="cpu")
        pred = heart.predict(ep.target_sites.numpy()).u
        out[route] = {
            "cc": [spatial_cc(p, t) for p, t in zip(pred, truth)],
            "error_ms": [activation_error_ms(p, a, times)[0] for p, a in zip(pred, true_act)],
        }
    return out


def unseen_folds(args) -> list[tuple]:
    """(subject, context rows, target rows) of each test subject of the model, drawn with a fixed seed."""
    test = list(load_checkpoint(args.model, kind="model")["splits"]["test"])
    view = StoreView(args.store)
    rng = np.random.default_rng(args.seed)
    folds = []
    for subject in test[: args.subjects or None]:
        rows = rng.permutation(len(view.sites(view.mesh_of[subject])))
        folds.append((subject, sorted(rows[: args.context]), sorted(rows[args.context : args.context + args.targets])))
    return folds


def real_folds(args) -> list[tuple]:
    """(subject, context rows, [left-out row]) of each real-heart subject and site that starts a wave."""
    view = StoreView(args.real)
    folds = []
    for subject in view.subjects:
        wave = started_wave(np.mean(np.isfinite(read_activation(args.real, subject)), axis=1))
        rows = np.flatnonzero(wave)
        folds += [(subject, [int(r) for r in rows if r != left], [int(left)]) for left in rows]
    return folds


def real_label(store: str) -> str:
    """``real:`` and the real hearts (mesh ids) of ``store``, in its order."""
    view = StoreView(store)
    return "real:" + ", ".join(dict.fromkeys(view.mesh_of[s] for s in view.subjects))


def summary(results: list[dict]) -> dict:
    """Means over every target of the folds, per route, and the difference of the CCs."""
    row = {}
    for route in [r for r in ("potentials", "activation", "every_frame") if r in results[0]]:
        cc = np.concatenate([r[route]["cc"] for r in results])
        err = np.concatenate([r[route]["error_ms"] for r in results])
        row[route] = {"cc": float(np.mean(cc)), "cc_std": float(np.std(cc)), "error_ms": float(np.nanmean(err))}
    row["difference"] = row["activation"]["cc"] - row["potentials"]["cc"]
    row["targets"] = int(sum(len(r["potentials"]["cc"]) for r in results))
    return row


def table(rows: list[dict]) -> list[str]:
    """The rows as a Markdown table; with a column of the maps read at every frame where the rows have one."""
    every = "every_frame" in rows[0]
    lines = [
        "| hearts | tissue | recorded nodes | targets | CC from potentials | CC from activation maps | difference "
        + ("| CC from maps read at every frame (difference) " if every else "")
        + "| activation error from potentials / maps (ms) |",
        "|---|---|---|---:|---:|---:|---:|" + ("---:|" if every else "") + "---:|",
    ]
    for r in rows:
        p, a = r["potentials"], r["activation"]
        full = f"| {r['every_frame']['cc']:.3f} ({r['every_frame']['cc'] - p['cc']:+.3f}) " if every else ""
        lines.append(
            f"| {r['hearts']} | {r['tissue']} | {r['observe']} | {r['targets']} | {p['cc']:.3f} +- {p['cc_std']:.3f} "
            f"| {a['cc']:.3f} +- {a['cc_std']:.3f} | {r['difference']:+.3f} {full}"
            f"| {p['error_ms']:.1f} / {a['error_ms']:.1f} |"
        )
    return lines


def by_tissue(folds: list[tuple], results: list) -> list[tuple[str, list]]:
    """The results of ``folds`` (subject, context, targets) grouped as all, healthy and scarred subjects; a group
    without a fold is left out."""
    healthy = [subject.endswith("-healthy") for subject, _, _ in folds]
    groups = [
        (tissue, [r for r, h in zip(results, healthy) if tissue == "all" or h == (tissue == "healthy")])
        for tissue in ("all", "healthy", "scarred")
    ]
    return [(tissue, kept) for tissue, kept in groups if kept]


def add_fold_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of :func:`unseen_folds` and :func:`real_folds`: the model, its store and the real heart's,
    the context and targets of each unseen subject, how many subjects, the seed."""
    parser.add_argument("--model", default="anatomies", help="shipped model name or checkpoint")
    parser.add_argument("--store", required=True, help="the model's training store (its test split is used)")
    parser.add_argument("--real", required=True, help="real-heart store (specs/realdata.toml)")
    parser.add_argument("--context", type=int, default=4, help="context sites per unseen subject")
    parser.add_argument("--targets", type=int, default=5, help="targets per unseen subject")
    parser.add_argument("--subjects", type=int, default=0, help="first N test subjects only (0: all)")
    parser.add_argument("--seed", type=int, default=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fold_arguments(parser)
    parser.add_argument("--observe", nargs="+", default=["electrodes", "surface", "endocardium"])
    parser.add_argument("--noise-ms", type=float, default=3.0, help="activation-time noise std (ms)")
    add_out_argument(parser, "activation_maps")
    add_publish_argument(parser, "activation_maps")
    args = parser.parse_args()
    check_publish(args.publish)
    ckpt = load_checkpoint(args.model, kind="model")
    maps_encoder = ckpt["config"]["model"].get("maps_encoder", False)
    args.every_frame = ApTemplate.from_dict(ckpt["ap_template"]) if maps_encoder else None
    start = time.perf_counter()
    rows = []
    for hearts, store, folds in (
        ("unseen sampled", args.store, unseen_folds(args)),
        (real_label(args.real), args.real, real_folds(args)),
    ):
        for observe in args.observe:
            results = [
                fold(args.model, store, s, c, t, observe, args, [args.seed, i]) for i, (s, c, t) in enumerate(folds)
            ]
            for tissue, keep in by_tissue(folds, results):
                rows.append(
                    {"hearts": hearts, "tissue": tissue, "observe": observe, "folds": len(keep), **summary(keep)}
                )
                print(table(rows[-1:])[-1], flush=True)
    text = [
        f"Machine: {machine_line()}. Model `{args.model}`; potentials with noise {NOISE_U} (u), activation maps "
        f"with noise {args.noise_ms:g} ms; unseen hearts: {args.context} context and {args.targets} target sites "
        "per test subject; real heart: leave one site out.",
        "",
        *table(rows),
        "",
        f"{time.perf_counter() - start:.0f} s in all.",
    ]
    print("\n".join(text))
    write_out(args.out, "activation_maps", "\n".join(text) + "\n", {"machine": machine(), "rows": rows})
    publish_out(args.publish, "activation_maps", "\n".join(text[:-2]))


if __name__ == "__main__":
    main()
