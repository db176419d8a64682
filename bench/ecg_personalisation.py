"""Benchmark: personalising from the 12-lead ECG against personalising from the epicardial sock.

For every fold a shipped model (``--model``, default ``anatomies``) is personalised twice on the same context
pacings: once on the sock's potentials (the 247 electrodes, noise 0.02 on ``u``, as in training) and once on
the 12-lead pseudo-ECGs of the same simulations (standard electrodes placed by the heart's axes, the
subject's tissue weighing the conductivity, Gaussian noise of ``--ecg-noise`` times the largest lead value),
which its ECG encoder reads (:mod:`learner.models.ecg_encoder`). Both predict the same unrecorded sites; the
table gives the spatial CC and activation-time error of each, and the CC over time of each lead of the
predicted ECG (the prediction through the mesh's healthy lead field) against the simulated one.

* Unseen hearts: the model's test split of ``--store``, ``--context`` random context and ``--targets`` target
  sites per subject.
* Real heart: ``--real`` (``specs/realdata.toml``), each site that starts a wave left out in turn.

FS-BO (:class:`~learner.baselines.FSBO`, ``--bo-budget`` simulations) is fitted to the ECG and to the sock on
the first ``--bo-folds`` real-heart folds of each tissue setting, with its time per fit.

Run::

    .venv/bin/python -m bench.ecg_personalisation --store data/pretrained.zarr --real data/realdata.zarr \
        --out report/bench

``--publish`` writes the tables into the block ``ecg_personalisation`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch
import zarr

from bench.activation_maps import NOISE_U, add_fold_arguments, by_tissue, real_folds, real_label, unseen_folds
from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from learner.baselines import FSBO
from learner.data.episodes import load_episode, subject_lead_fields
from learner.metrics import activation_error_ms, spatial_cc
from learner.observations import Observations
from learner.personalized import NoWaveWarning, personalize
from learner.refine import Refinement
from learner.store_view import StoreView
from shared.ecg import LEADS
from shared.reader import read_activation

ROUTES = ("sock", "ecg")
#: The ECG route with ``c`` refined on the ECGs (``--refine-steps``).
REFINED = "ecg, refined"


def lead_cc(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(12,) Pearson correlation over time of each lead of ECGs (12, T); NaN for a flat lead."""
    p = pred - pred.mean(axis=-1, keepdims=True)
    t = truth - truth.mean(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (p * t).sum(-1) / np.sqrt((p * p).sum(-1) * (t * t).sum(-1))


def observations(store: str, subject: str, context: list[int], targets: list[int], args, seed) -> dict:
    """The fold's two recordings of its context (Observations per route) and its truth."""
    view = StoreView(store)
    mesh = view.mesh(view.mesh_of[subject])
    sock = load_episode(store, subject, context, targets, "electrodes", NOISE_U, np.random.default_rng(seed))
    ecg = load_episode(store, subject, context, targets, "electrodes", 0.0, np.random.default_rng(seed), args.ecg_noise)
    sites, times = sock.context_sites.numpy(), sock.times.numpy()
    nobody = np.zeros(mesh.n_nodes, bool)
    truth_field, _ = subject_lead_fields(store, subject, view.mesh_of[subject])
    return {
        "sock": Observations(mesh, sites, sock.context_obs.numpy(), sock.observed.numpy(), times, subject),
        "ecg": Observations(mesh, sites, None, nobody, times, subject, ecg=ecg.context_ecg.numpy()),
        "targets": sock.target_sites.numpy(),
        "truth": sock.target_u.numpy(),
        "truth_ecg": truth_field.ecg(sock.target_u).numpy(),
        "activation": read_activation(store, subject, targets),
        "times": times,
    }


def fold(model: str, store: str, subject: str, context: list[int], targets: list[int], args, seed) -> dict:
    """Per route: spatial CC, activation error (ms) and per-lead ECG CC of each target, and seconds to
    personalise."""
    data = observations(store, subject, context, targets, args, seed)
    data[REFINED] = data["ecg"]
    out = {}
    for route in routes(args):
        refine = Refinement(steps=args.refine_steps if route == REFINED else 0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NoWaveWarning)
            heart = personalize(model, data[route], device="cpu", refine=refine)
        prediction = heart.predict(data["targets"])
        ecg = prediction.ecg
        if ecg is None:  # a heart personalised on potentials: its prediction through the same lead field
            _, healthy = subject_lead_fields(store, subject, StoreView(store).mesh_of[subject])
            ecg = healthy.ecg(torch.as_tensor(prediction.u)).numpy()
        out[route] = {
            "cc": [spatial_cc(p, t) for p, t in zip(prediction.u, data["truth"])],
            "error_ms": [activation_error_ms(p, a, data["times"])[0] for p, a in zip(prediction.u, data["activation"])],
            "lead_cc": [lead_cc(p, t) for p, t in zip(ecg, data["truth_ecg"])],
            "seconds": heart.embed_seconds,
        }
    return out


def routes(args) -> tuple[str, ...]:
    """The routes a run compares: the sock, the ECG and, with ``--refine-steps``, the ECG refined."""
    return (*ROUTES, REFINED) if args.refine_steps else ROUTES


def bo_fold(store: str, subject: str, context: list[int], targets: list[int], args, seed) -> dict:
    """FS-BO fitted to each route's recordings: spatial CC at the targets and seconds per fit."""
    data = observations(store, subject, context, targets, args, seed)
    solver = dict(zarr.open_group(store, mode="r").attrs["spec"]["solver"])
    out = {}
    for route in ROUTES:
        baseline = FSBO(budget=args.bo_budget, seed=args.seed)
        result = baseline.fit(data[route], solver)
        pred = baseline.predict(data["targets"])
        out[route] = {"cc": [spatial_cc(p, t) for p, t in zip(pred, data["truth"])], "seconds": result.seconds}
    return out


def summary(results: list[dict]) -> dict:
    """Means over every target of the folds, per route."""
    row = {"targets": int(sum(len(r["sock"]["cc"]) for r in results))}
    for route in results[0]:
        cc = np.concatenate([r[route]["cc"] for r in results])
        err = np.concatenate([r[route]["error_ms"] for r in results])
        leads = np.concatenate([np.stack(r[route]["lead_cc"]) for r in results])
        row[route] = {
            "cc": float(np.mean(cc)),
            "cc_std": float(np.std(cc)),
            "error_ms": float(np.nanmean(err)),
            "lead_cc": np.nanmean(leads, axis=0).round(4).tolist(),
            "seconds": float(np.mean([r[route]["seconds"] for r in results])),
        }
    return row


def tables(rows: list[dict], bo_rows: list[dict]) -> list[str]:
    return (surrogate_tables(rows) if rows else []) + bo_table(bo_rows)


def surrogate_tables(rows: list[dict]) -> list[str]:
    """Per route: the metrics table and the per-lead ECG correlations."""
    lines = [
        "| hearts | tissue | targets | route | spatial CC | activation error (ms) | ECG CC, mean of the 12 leads "
        "| s to personalise |",
        "|---|---|---:|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        for route in [k for k in r if k in (*ROUTES, REFINED)]:
            m = r[route]
            lines.append(
                f"| {r['hearts']} | {r['tissue']} | {r['targets']} | from the {route} | {m['cc']:.3f} +- "
                f"{m['cc_std']:.3f} | {m['error_ms']:.1f} | {np.nanmean(m['lead_cc']):.3f} | {m['seconds']:.2f} |"
            )
    lines += ["", "| hearts | tissue | route | " + " | ".join(LEADS) + " |", "|---|---|---|" + "---:|" * len(LEADS)]
    for r in rows:
        if r["tissue"] == "all":
            for route in [k for k in r if k in (*ROUTES, REFINED)]:
                values = " | ".join(f"{v:.2f}" for v in r[route]["lead_cc"])
                lines.append(f"| {r['hearts']} | all | from the {route} | {values} |")
    return lines


def bo_table(bo_rows: list[dict]) -> list[str]:
    """FS-BO fitted to the sock and to the ECG: CC at the targets and seconds per fit (none without rows)."""
    if not bo_rows:
        return []
    lines = [
        "",
        "| FS-BO on | tissue | folds | targets | CC fitted to the sock | CC fitted to the ECG "
        "| s per fit, sock / ECG |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in bo_rows:
        lines.append(
            f"| {r['hearts']} | {r['tissue']} | {r['folds']} | {r['targets']} | {r['sock']['cc']:.3f} "
            f"| {r['ecg']['cc']:.3f} | {r['sock']['seconds']:.0f} / {r['ecg']['seconds']:.0f} |"
        )
    return lines


def first_folds(folds: list[tuple], n: int) -> list[tuple]:
    """The first ``n`` folds of each subject (0: all)."""
    subjects = sorted({s for s, _, _ in folds})
    return [f for subject in subjects for f in [f for f in folds if f[0] == subject][: n or None]]


def bo_summary(results: list[dict], hearts: str, tissue: str) -> dict:
    row = {"hearts": hearts, "tissue": tissue, "folds": len(results)}
    row["targets"] = int(sum(len(r["sock"]["cc"]) for r in results))
    for route in ROUTES:
        cc = np.concatenate([r[route]["cc"] for r in results])
        row[route] = {"cc": float(np.mean(cc)), "seconds": float(np.mean([r[route]["seconds"] for r in results]))}
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fold_arguments(parser)
    parser.add_argument("--ecg-noise", type=float, default=0.02, help="ECG noise std, share of the largest value")
    parser.add_argument("--real-folds", type=int, default=0, help="first N real-heart folds per tissue (0: all)")
    parser.add_argument("--refine-steps", type=int, default=0, help="also the ECG route refined by up to N steps")
    parser.add_argument("--bo-folds", type=int, default=2, help="FS-BO real-heart folds per tissue setting (0: none)")
    parser.add_argument("--bo-budget", type=int, default=40, help="FS-BO simulations per fit")
    parser.add_argument("--bo-unseen", type=int, default=0, help="FS-BO on the first N unseen subjects too")
    parser.add_argument("--bo-only", action="store_true", help="FS-BO alone (the surrogate's folds left out)")
    add_out_argument(parser, "ecg_personalisation")
    add_publish_argument(parser, "ecg_personalisation")
    args = parser.parse_args()
    check_publish(args.publish)
    start = time.perf_counter()
    rows, bo_rows = [], []
    real, unseen = first_folds(real_folds(args), args.real_folds), unseen_folds(args)
    sets = (("unseen sampled", args.store, unseen), (real_label(args.real), args.real, real))
    for hearts, store, folds in sets[: 0 if args.bo_only else 2]:
        results = [fold(args.model, store, s, c, t, args, [args.seed, i]) for i, (s, c, t) in enumerate(folds)]
        for tissue, keep in by_tissue(folds, results):
            rows.append({"hearts": hearts, "tissue": tissue, "folds": len(keep), **summary(keep)})
            print("\n".join(tables(rows[-1:], [])[2 : 2 + len(routes(args))]), flush=True)
    bo_sets = (
        ("unseen sampled", args.store, unseen[: args.bo_unseen]),
        (real_label(args.real), args.real, first_folds(real, args.bo_folds) if args.bo_folds else []),
    )
    for hearts, store, chosen in bo_sets:
        if not chosen:
            continue
        results = [bo_fold(store, s, c, t, args, [args.seed, i]) for i, (s, c, t) in enumerate(chosen)]
        for tissue, keep in by_tissue(chosen, results):
            if keep:
                bo_rows.append(bo_summary(keep, hearts, tissue))
    text = [
        f"Machine: {machine_line()}. Model `{args.model}`; the sock with noise {NOISE_U} (u), ECGs with noise "
        f"{args.ecg_noise:g} of the largest lead value; unseen hearts: {args.context} context and {args.targets} "
        f"target sites per test subject; real heart: leave one site out"
        + (f" (the first {args.real_folds} folds of each tissue setting)" if args.real_folds else "")
        + (f"; refined: up to {args.refine_steps} steps" if args.refine_steps else "")
        + (f"; FS-BO: {args.bo_budget} simulations per fit" if args.bo_folds or args.bo_unseen else "")
        + (f", the first {args.bo_folds} real-heart folds of each tissue setting" if args.bo_folds else "")
        + (f", the first {args.bo_unseen} unseen subjects" if args.bo_unseen else "")
        + ".",
        "",
        *tables(rows, bo_rows),
        "",
        f"{time.perf_counter() - start:.0f} s in all.",
    ]
    print("\n".join(text))
    data = {"machine": machine(), "rows": rows, "bo": bo_rows}
    write_out(args.out, "ecg_personalisation", "\n".join(text) + "\n", data)
    publish_out(args.publish, "ecg_personalisation", "\n".join(text[:-2]))


if __name__ == "__main__":
    main()
