"""Benchmark: the BO baselines (FS-BO, VAE-BO) on every fold of the real heart, and what one fit costs.

Runs the baselines of ``--config``'s ``[baselines]`` (``specs/benchmark-default.toml``: budget 100
simulator calls per fit, FS-BO on 7 regions, seed 0) on the real-heart store of ``--store``
(``specs/realdata.toml``: the shipped MRI biventricle ``real:tof-biv``, 3 tissue settings) with the
config's real-data observation model (the 247-electrode epicardial sock, noise 0.02, leaving one of
8 pacing sites out in turn), through ``learner.benchmark.real_data``: the same folds, noise draws
and metrics as ``learner benchmark``, here on every fold (``--folds 0``) instead of the first
``baseline_folds``. Prints the target MSE, spatial and temporal CC (mean ± std over the folds) per
method beside the noise-free truth scored the same way (the ceiling), and the wall time of each fit:
the first (for VAE-BO it includes building the scar library and training the VAE, once per mesh),
the mean per fold, and the share spent inside the simulator. ``--models`` scores trained models
(checkpoints, or shipped names such as ``anatomies``) on the same folds, their rows first.

Run (one thread for the simulator and for the GP)::

    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python -m bench.real_baselines \\
        --store data/realdata.zarr --models anatomies --out report/bench   # every fold, both methods
    .venv/bin/python -m bench.real_baselines --folds 1 --methods fs-bo   # first fold of each subject

``--out DIR`` writes real_baselines.md (the tables) and real_baselines.json (every fold and fit).
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np
from torch import Tensor

from bench.common import add_out_argument, machine, machine_line, write_out
from learner.benchmark import BenchmarkConfig, baseline_methods, load_benchmark_config, real_data, real_data_setting
from learner.benchmark_report import real_data_table
from learner.config import ModelConfig
from learner.data.episodes import Episode
from learner.evaluate import EvalSetting, Method, load_method
from learner.graph.hierarchy import MeshHierarchy
from learner.methods import BaselineMethod
from learner.store_view import StoreView
from shared.mesh import Mesh
from shared.observation import Observation
from shared.reader import read_solver_settings


class TimedFit(Method):
    """A BO baseline that records the wall time and cost of each of its fits."""

    def __init__(self, inner: BaselineMethod) -> None:
        self.inner, self.name, self.fits = inner, inner.name, []

    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        t0 = time.perf_counter()
        cost = self.inner.fit(episode, mesh, hierarchy)
        result = self.inner.baseline.result
        self.fits.append(
            {
                "subject": episode.subject_id,
                "wall_s": time.perf_counter() - t0,
                "setup_s": result.setup_seconds,
                "simulate_s": result.simulate_seconds,
                "calls": cost["calls"],
                "objective": result.objective,
            }
        )
        print(f"{self.name} {episode.subject_id} fit {len(self.fits)}: {self.fits[-1]['wall_s']:.1f} s", flush=True)
        return cost

    def predict(self, sites: Tensor) -> np.ndarray:
        return self.inner.predict(sites)


def timing_table(methods: list[TimedFit]) -> str:
    """Markdown: per method, the folds, the first fit, the mean fit and its setup and simulator shares."""
    lines = [
        "| method | folds | first fit (s) | mean fit (s) | mean setup (s) | in the simulator | calls per fit |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m in methods:
        wall = np.array([f["wall_s"] for f in m.fits])
        setup = np.mean([f["setup_s"] for f in m.fits])
        sim = sum(f["simulate_s"] for f in m.fits) / wall.sum()
        lines.append(
            f"| {m.name} | {len(wall)} | {wall[0]:.1f} | {wall.mean():.1f} ± {wall.std():.1f} | {setup:.1f} "
            f"| {100 * sim:.0f} % | {m.fits[0]['calls']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def score_models(refs: list[str], cfg: BenchmarkConfig, folds: int, result: dict) -> dict[str, float]:
    """Score each trained model of ``refs`` on the folds of ``result`` (the same sites, noise draws and
    metrics, each model with its own mesh hierarchy) and add its rows, named by its reference, before the
    baselines'; the wall seconds of each."""
    seconds, methods, rows = {}, {}, {}
    for ref in refs:
        method, config, _ = load_method(ref)
        start = time.perf_counter()
        scored = real_data([method], real_data_setting(cfg, EvalSetting.of(config)), cfg, folds)
        seconds[ref] = time.perf_counter() - start
        methods[ref], rows[ref] = scored["methods"][method.name], scored["folds"][method.name]
    result["methods"] = {**methods, **result["methods"]}
    result["folds"] = {**rows, **result["folds"]}
    return seconds


def report(header: str, result: dict, methods: list[TimedFit], model_seconds: dict[str, float]) -> str:
    """The printed report: ``header``, the metrics of every method, the baselines' fit times (where any
    ran) and each trained model's seconds for all its folds."""
    parts = [header, real_data_table(result)]
    if methods:
        parts.append(timing_table(methods))
    if model_seconds:
        parts.append("".join(f"- {ref}: {seconds:.1f} s for all its folds\n" for ref, seconds in model_seconds.items()))
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--store", default="data/realdata.zarr", help="real-heart store (specs/realdata.toml)")
    p.add_argument("--config", default="specs/benchmark-default.toml", help="benchmark config: [baselines], seed")
    p.add_argument("--methods", nargs="*", default=["fs-bo", "vae-bo"], help="baselines to run")
    p.add_argument(
        "--models",
        nargs="*",
        default=[],
        metavar="REF",
        help="trained models scored on the same folds: checkpoints or shipped names (e.g. anatomies)",
    )
    p.add_argument("--folds", type=int, default=0, help="left-out sites per subject (0: all)")
    add_out_argument(p, "real_baselines")
    args = p.parse_args(argv)

    cfg = load_benchmark_config(args.config)
    cfg = replace(cfg, real_data=replace(cfg.real_data, store=args.store))
    view = StoreView(args.store)
    baselines = baseline_methods(cfg, read_solver_settings(view.store), view.times, tuple(args.methods))
    methods = [TimedFit(m) for m in baselines]
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    model = ModelConfig()  # the hierarchy real_data builds; the baselines do not use it
    setting = real_data_setting(cfg, EvalSetting(Observation(), model.levels, model.coarsest, model.working_nodes))
    result = real_data(methods, setting, cfg, args.folds)
    model_seconds = score_models(args.models, cfg, args.folds, result)
    total = time.perf_counter() - start
    load_after = os.getloadavg()[0]

    mesh = view.mesh(view.mesh_of[view.subjects[0]])
    folds = len(result["folds"]["ceiling"])
    rd, b = cfg.real_data, cfg.baselines
    header = (
        f"Real-heart baselines: {machine_line()}, "
        f"one thread; total {total:.0f} s; 1-min load average {load_before:.1f} before, {load_after:.1f} after.\n\n"
        f"{', '.join(result['subjects'])} ({mesh.n_nodes} nodes), {result['electrodes']} sock electrodes, "
        f"noise {rd.noise_std}, leave one of {rd.sites} sites out: {folds} folds "
        f"({'all' if args.folds <= 0 else f'the first {args.folds}'} of each subject); budget {b.budget} "
        f"simulator calls per fit, FS-BO on {b.regions} regions, seed {cfg.seed}.\n"
    )
    text = report(header, result, methods, model_seconds)
    print(text)
    meta = {
        **machine(),
        "load_before": load_before,
        "load_after": load_after,
        "total_s": total,
        "nodes": mesh.n_nodes,
        "folds_per_subject": args.folds,
        "fits": {m.name: m.fits for m in methods},
        "model_seconds": model_seconds,
        **result,
    }
    write_out(args.out, "real_baselines", text, meta)


if __name__ == "__main__":
    main()
