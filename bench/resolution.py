"""Benchmark: a surrogate that answers at any resolution. One heart meshed at 1k to 100k nodes, personalised.

A shipped real heart (``--heart``, default ``real:tof-biv``) is meshed at
``--nodes`` (default 1k, 2k, 5k, 20k and 100k) and, at every resolution, the
truth simulated there from the same ``--sites`` pacing positions (points of
the finest mesh's epicardium spread by farthest-point sampling, each stimulus
centred on its point) under each ``--tissue`` setting. The recordings are the
247 sock electrodes of that mesh with Gaussian noise 0.02 (seeded), as the
shipped model's real-heart evaluation. Every fold leaves one site out: the
model (``--model``, default the shipped ``anatomies``) is personalised on the
other sites' recordings (those that start a wave) and predicts the one left
out, on every node of the mesh; spatial CC and MSE against the simulated truth
and the mean activation-time error (ms) over the nodes activated in both.

Per resolution: the mean over folds and tissue settings, its difference from
the coarsest resolution's (the goal: within 0.02 at every resolution), the
same prediction's CC against the finest mesh's truth interpolated onto this
mesh's nodes (the converged answer: this column separates what the model does
at a resolution from what the physics does there, bench/convergence.py), the
working graph the model ran on, and the cost of personalising (first call:
building the working graph included) and of predicting one site (the peak
memory of a fresh process per resolution: bench/predict.py). ``--model``
takes several models (shipped names or checkpoints) and writes one table
each.

Run::

    .venv/bin/python -m bench.resolution --out report/bench      # ~20 min on 2 cores (100k: meshing ~5 min)
    .venv/bin/python -m bench.resolution --nodes 1000 2000 5000 --tissue healthy

Meshes are cached in ``--cache`` (shared with bench/convergence.py).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from bench.common import add_out_argument, machine, machine_line, write_out
from bench.convergence import TISSUES, cached_mesh, pacing_positions
from learner.metrics import activation_error_ms, mse, spatial_cc
from learner.observations import Observations
from learner.personalized import NoWaveWarning, personalize
from shared.interpolation import interpolation_matrix
from shared.observation import observe
from shared.sites import nearest_nodes
from simgen.observe import Sock
from simgen.solver.simulate import Simulator
from simgen.tissue import default_settings, tissue_fields

#: The goal: the spatial CC at every resolution within this of the coarsest resolution's.
GOAL_DELTA = 0.02
NOISE = 0.02


def resolution_row(
    model: str, source: str, nodes: int, positions: np.ndarray, finest: dict, args: argparse.Namespace
) -> dict:
    """Every tissue setting and leave-one-site-out fold at one resolution (module docstring).

    ``finest`` maps each tissue to the finest mesh's ``(mesh, u)``; the finest row fills it."""
    mesh = cached_mesh(source, nodes, args.cache)[0]
    sites = nearest_nodes(mesh.points, positions, np.inf)  # the node nearest each pacing point
    observed = np.zeros(mesh.n_nodes, bool)
    observed[Sock().indices(mesh)] = True
    settings = {s.name: s for s in default_settings()}
    ccs, converged, errors, msqe, personalise_s, predict_s, working, by_tissue = [], [], [], [], [], [], None, {}
    for t, tissue in enumerate(args.tissue):
        truth = Simulator(mesh, tissue_fields(mesh, settings[tissue])).run(sites, threads=2, centres=positions)
        fine, fine_u = finest.setdefault(tissue, (mesh, truth.u))
        reference = fine_u if fine is mesh else interpolated(fine, fine_u, mesh)
        noisy = observe(truth.u, observed, NOISE, np.random.default_rng([args.seed, t]))
        for left in range(len(sites)):
            if not truth.started_wave[left]:
                continue  # a site in a scar core: no wave to predict
            keep = [k for k in range(len(sites)) if k != left and truth.started_wave[k]]
            context = Observations(mesh, sites[keep], noisy[keep], observed, truth.times, f"{tissue}-{left}")
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NoWaveWarning)
                heart = personalize(model, context, device="cpu")
            personalise_s.append(time.perf_counter() - start)
            start = time.perf_counter()
            u = heart.predict([sites[left]]).u[0]
            predict_s.append(time.perf_counter() - start)
            ccs.append(spatial_cc(u, truth.u[left]))
            converged.append(spatial_cc(u, reference[left]))
            by_tissue.setdefault(tissue, []).append(ccs[-1])
            msqe.append(mse(u, truth.u[left]))
            errors.append(activation_error_ms(u, truth.activation[left], truth.times)[0])
            working = heart.hierarchy.sizes[0]
    return {
        "model": model,
        "target": nodes,
        "nodes": mesh.n_nodes,
        "working": working,
        "folds": len(ccs),
        "cc": float(np.mean(ccs)),
        "cc_std": float(np.std(ccs)),
        "cc_by_tissue": {tissue: float(np.mean(values)) for tissue, values in by_tissue.items()},
        "cc_converged": float(np.mean(converged)),
        "mse": float(np.mean(msqe)),
        "activation_error_ms": float(np.nanmean(errors)),
        "personalize_first_s": personalise_s[0],
        "personalize_s": float(np.median(personalise_s[1:] or personalise_s)),
        "predict_s": float(np.median(predict_s)),
    }


def interpolated(fine, u: np.ndarray, mesh) -> np.ndarray:
    """Sequences ``u`` (S, T, N_fine) of mesh ``fine`` at the nodes of ``mesh`` (P1), (S, T, N)."""
    weights = interpolation_matrix(fine.points, fine.cells, mesh.points)
    return (weights @ u.reshape(-1, u.shape[-1]).T).T.reshape(*u.shape[:2], mesh.n_nodes)


def table(rows: list[dict]) -> list[str]:
    """The Markdown table of one model's rows, with each row's CC against the coarsest row's."""
    base = rows[0]["cc"]
    lines = [
        "| nodes | working graph | folds | spatial CC | vs coarsest | CC vs finest mesh's truth | MSE "
        "| activation error (ms) | personalise, first / later (s) | predict 1 site (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['nodes']} | {r['working']} | {r['folds']} | {r['cc']:.3f} +- {r['cc_std']:.3f} "
            f"| {r['cc'] - base:+.3f} | {r['cc_converged']:.3f} | {r['mse']:.4f} | {r['activation_error_ms']:.1f} "
            f"| {r['personalize_first_s']:.2f} / {r['personalize_s']:.2f} | {r['predict_s']:.3f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", nargs="+", default=["anatomies"], help="shipped names or checkpoints")
    parser.add_argument("--heart", default="real:tof-biv")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 2000, 5000, 20_000, 100_000])
    parser.add_argument("--tissue", nargs="+", default=list(TISSUES))
    parser.add_argument("--sites", type=int, default=8, help="pacing positions (leave-one-out folds)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the observation noise")
    parser.add_argument("--cache", type=Path, default=Path("report/bench/convergence-meshes"))
    add_out_argument(parser, "resolution")
    args = parser.parse_args()
    args.nodes = sorted(args.nodes)
    positions = pacing_positions(cached_mesh(args.heart, args.nodes[-1], args.cache)[0], args.sites)
    start = time.perf_counter()
    text, rows = (
        [
            f"Machine: {machine_line()}. {args.heart}, {len(args.tissue)} tissue settings x {args.sites} "
            f"pacing sites, 247 sock electrodes, noise {NOISE}, leave one site out."
        ],
        [],
    )
    finest: dict = {}
    for model in args.model:
        model_rows = []
        for nodes in reversed(args.nodes):  # the finest first: its truth is every row's converged answer
            model_rows.insert(0, resolution_row(model, args.heart, nodes, positions, finest, args))
            print(table(model_rows[:1])[-1], flush=True)
        worst = max(abs(r["cc"] - model_rows[0]["cc"]) for r in model_rows)
        verdict = "meets" if worst <= GOAL_DELTA else "misses"
        text += [
            "",
            f"Model `{model}`:",
            "",
            *table(model_rows),
            "",
            f"Largest CC difference from {model_rows[0]['nodes']} nodes: {worst:.3f} ({verdict} the "
            f"{GOAL_DELTA} goal).",
        ]
        rows += model_rows
    text.append(f"\n{time.perf_counter() - start:.0f} s in all.")
    print("\n".join(text))
    write_out(args.out, "resolution", "\n".join(text) + "\n", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
