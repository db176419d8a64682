"""One command for the paper's comparison: Table 1, Fig. 3, timings, maps, calibration, real-data emulation.

``learner benchmark CONFIG`` loads (or trains) metaPNS and PNS, evaluates them on
the test subjects, runs the two Bayesian-optimisation baselines (FS-BO, VAE-BO)
on a subset of them with the same context sets, and writes ``<out>/``:

* ``benchmark.md`` - everything below as Markdown, ``benchmark.json`` - the numbers;
* ``table1.md`` - context / target MSE, CC, DC and activation-time error per method;
* ``fig3_context.png`` - target accuracy against context size 1-5 (metaPNS vs PNS);
* ``timing.md`` - one simulation, one surrogate generation, context embedding, BO personalisation;
* ``activation_maps-<subject>.png`` - truth vs every method on one target of the baseline subset (the table's fits);
* uncertainty: how often the truth falls inside metaPNS's 90% band from samples of c;
* real-data emulation (when ``real_data.store`` is set): a geometry never seen in training, observed
  through the epicardial sock with noise, one pacing site left out at a time: metaPNS and PNS on every
  fold, the BO baselines too on the first ``real_data.baseline_folds`` of each subject.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from learner.benchmark_report import write_report
from learner.data.episodes import Episode, load_episode
from learner.evaluate import EvalReport, EvalSetting, EvalSpec, Method, NeuralMethod, evaluate_methods
from learner.methods import BASELINES, NEURAL, BaselineMethod, MethodContext, build_methods
from learner.metrics import mse, spatial_cc, temporal_cc
from learner.models.site_evidence import SiteEvidence
from learner.pretrained import resolve_reference
from learner.runtime import on_device, resolve_device
from learner.store_view import StoreView
from learner.train.trainer import load_model
from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import ConfigError, InputError
from shared.location import resolve_location
from shared.observation import Observation, gaussian_noise
from shared.reader import read_solver_settings, read_tissue
from shared.simulator import load_simulator

__all__ = [
    "BaselineSpec",
    "RealDataSpec",
    "BenchmarkConfig",
    "load_benchmark_config",
    "BaselineMethod",
    "baseline_methods",
    "calibration",
    "real_data_setting",
    "real_data",
    "observe_fold",
    "run_benchmark",
]


@dataclass(frozen=True)
class BaselineSpec:
    """The BO baselines: which, on how many test subjects (paper: 11 of 16), with what budget."""

    methods: tuple[str, ...] = ("fs-bo", "vae-bo")
    subjects: int = 4
    context_sets: int = 1
    max_targets: int = 10
    budget: int = 100
    regions: int = 7


@dataclass(frozen=True)
class RealDataSpec:
    """Real-data emulation: a store whose geometry training never saw, observed by the sock."""

    store: str = ""  # empty: skipped
    observe: str = "electrodes"
    noise_std: float = 0.02
    sites: int = 4
    baseline_folds: int = 0  # left-out sites per subject on which the BO baselines run too (0: none)


@dataclass(frozen=True)
class BenchmarkConfig:
    """What ``learner benchmark`` runs (paths relative to the config file)."""

    out: str = "report/benchmark"
    store: str = ""
    metapns: str = ""  # checkpoints (best.pt) of the two models; a shipped model's name works too
    pns: str = ""
    context: tuple[int, int] = (1, 5)
    context_sets: int = 3
    max_targets: int = 40
    seed: int = 0
    context_sizes: tuple[int, ...] = (1, 2, 3, 4, 5)
    curve_sets: int = 2
    curve_targets: int = 20
    samples: int = 20  # draws of c for the predictive band
    calibration_subjects: int = 4  # test subjects of the calibration check
    maps: int = 2  # subjects of the baseline subset drawn in the activation-map figure
    baselines: BaselineSpec = field(default_factory=BaselineSpec)
    real_data: RealDataSpec = field(default_factory=RealDataSpec)


def load_benchmark_config(path: str | Path) -> BenchmarkConfig:
    """Read a benchmark TOML; relative paths are resolved against its folder."""
    path = Path(path)
    cfg = from_mapping(BenchmarkConfig, load_toml(path))
    rel = partial(resolve_location, base=path.parent)
    for name in ("store", "metapns", "pns"):
        if not getattr(cfg, name):
            raise ConfigError(f"{path}: `{name}` is required")
    return replace(
        cfg,
        out=rel(cfg.out),
        store=rel(cfg.store),
        metapns=resolve_reference(cfg.metapns, path.parent),
        pns=resolve_reference(cfg.pns, path.parent),
        real_data=replace(cfg.real_data, store=rel(cfg.real_data.store)),
    )


def baseline_methods(
    cfg: BenchmarkConfig, solver: dict, times: np.ndarray, names: tuple[str, ...] | None = None
) -> list[Method]:
    """Fresh BO baselines ``names`` (default ``cfg.baselines.methods``) with the config's budget, regions and seed.

    ``solver`` and ``times`` are those of the store they will be fitted on.
    """
    b = cfg.baselines
    context = MethodContext(solver=solver, times=times, budget=b.budget, regions=b.regions, seed=cfg.seed)
    return build_methods(b.methods if names is None else names, context, among=BASELINES)


def _stats(report: EvalReport) -> dict:
    return {"overall": report.overall, "by_context_size": report.by_context_size, "timing": report.timing}


NOISE_DRAWS = 10  # Gaussian model-error draws per sample of c in the calibration band


def calibration(model, view: StoreView, subjects: list[str], cfg: BenchmarkConfig, setting: EvalSetting) -> dict:
    """How often target values fall inside the 5-95% band of two predictive distributions.

    * ``c`` only: samples of ``c ~ p(c | Y)`` through the generator (the
      model's epistemic spread about the subject);
    * ``c`` + noise: the same draws plus Gaussian model error ``N(0, s^2)``,
      with ``s`` the root-mean-square residual of the draws on the context's
      observed values: the subject's own misfit, known without the targets.
      ``NOISE_DRAWS`` noise draws per ``c``.

    The context is observed on ``setting``'s node set without observation noise.
    """
    tally = {"noise": np.zeros(2), "c": np.zeros(2)}  # values inside the band, summed band width
    n, device = 0, next(model.parameters()).device
    g = torch.Generator().manual_seed(cfg.seed)
    for si, subject in enumerate(subjects):
        mesh_id = view.mesh_of[subject]
        hier = on_device(setting.hierarchy(view, mesh_id), device)
        rng = np.random.default_rng([cfg.seed, si, 99])
        perm = rng.permutation(len(view.sites(mesh_id)))
        ep = load_episode(view.store, subject, perm[:3], np.sort(perm[3:8]), setting.observation.nodes)
        k = len(ep.context_sites)
        sites = torch.cat([ep.context_sites, ep.target_sites])
        with torch.no_grad():
            post = model.embed(ep.context_obs.to(device), ep.observed.to(device), hier)
            evidence = SiteEvidence.of(ep).to(device)
            draws = [model.generate(sites, hier, post.sample(g), evidence=evidence) for _ in range(cfg.samples)]
            draws = torch.stack(draws).cpu()
        residual = draws[:, :k][..., ep.observed] - ep.context_obs[..., ep.observed]
        noise_scale = residual.pow(2).mean().sqrt()
        targets = draws[:, k:]
        noisy = targets.unsqueeze(1) + noise_scale * torch.randn(
            (cfg.samples, NOISE_DRAWS, *targets.shape[1:]), generator=g
        )
        truth = ep.target_u
        for name, band in (("c", targets), ("noise", noisy.flatten(0, 1))):
            lo, hi = torch.quantile(band, 0.05, dim=0), torch.quantile(band, 0.95, dim=0)
            tally[name] += (float(((truth >= lo) & (truth <= hi)).sum()), float((hi - lo).sum()))
        n += truth.numel()
    (inside, width), (inside_c, width_c) = tally["noise"] / max(n, 1), tally["c"] / max(n, 1)
    return {
        "coverage_90": float(inside),
        "mean_band_width": float(width),
        "coverage_90_c_only": float(inside_c),
        "mean_band_width_c_only": float(width_c),
        "samples": cfg.samples,
        "subjects": len(subjects),
    }


def observe_fold(
    store: str, subject: str, context_rows: list[int], left: int, observation: Observation, rng: np.random.Generator
) -> tuple[Episode, np.ndarray]:
    """A real-data fold as observed: the context episode and the noisy recording of the left-out site ``left``.

    ``rng`` draws the context noise (as it would for a training episode: :func:`shared.observation.observe`)
    and then the recording's, in float64.
    """
    ep = load_episode(store, subject, context_rows, [left], observation.nodes, observation.noise_std, rng)
    recording = ep.target_u[0].numpy() + gaussian_noise(ep.target_u[0].shape, observation.noise_std, rng, np.float64)
    return ep, recording


def real_data_setting(cfg: BenchmarkConfig, setting: EvalSetting) -> EvalSetting:
    """``setting`` (the models' hierarchy) with the real-data observation: ``real_data.observe`` and its noise."""
    return replace(setting, observation=Observation(cfg.real_data.observe, cfg.real_data.noise_std))


def real_data(methods: list[Method], setting: EvalSetting, cfg: BenchmarkConfig, folds: int = 0) -> dict:
    """Leave one pacing site out on an unseen geometry observed by the sock (+ noise), for every method.

    Each of the store's subjects has ``real_data.sites`` pacing sites; each fold
    fits every method on the others and predicts the one left out (``folds > 0``:
    only the first ``folds`` of each subject, for the slow BO baselines). Metrics
    compare the prediction with the noisy sock signals at the electrodes, as the
    paper compares with in-vivo recordings. Returns the subjects, electrodes and
    noise, per method ``{"context": ..., "target": ...}`` means and stds, and
    the same for the ``ceiling``: the noise-free truth scored the same way, what
    a perfect method would get (below 1: frames where the heart is at rest or
    fully excited hold only noise, so their spatial CC is near 0 whatever the
    prediction). ``folds`` holds the target row of every fold, per method and
    for the ``ceiling``: where the error is. ``setting``: the models' hierarchy and the observation
    (:func:`real_data_setting`).
    """
    spec = cfg.real_data
    view, observation = StoreView(spec.store), setting.observation
    for m in methods:
        if isinstance(m, NeuralMethod) and view.frames != m.model.frames:
            raise InputError(f"{spec.store} has {view.frames} frames per simulation, {m.name} expects {m.model.frames}")
    rows: dict[str, list[dict]] = {m.name: [] for m in methods}
    ceiling: list[dict] = []
    for si, subject in enumerate(view.subjects):
        mesh_id = view.mesh_of[subject]
        mesh, hier = view.mesh(mesh_id), setting.hierarchy(view, mesh_id)
        n_sites = min(spec.sites, len(view.sites(mesh_id)))
        for left in range(n_sites if folds <= 0 else min(folds, n_sites)):
            ctx = [r for r in range(n_sites) if r != left]
            ep, noisy_target = observe_fold(
                view.store, subject, ctx, left, observation, np.random.default_rng([cfg.seed, si, left])
            )
            obs_nodes = ep.observed.numpy()
            truths = [*ep.context_obs.numpy(), noisy_target]
            fold = {"subject": subject, "left_out": left}
            ceiling += _fold_rows([*ep.context_u.numpy(), ep.target_u[0].numpy()], truths, obs_nodes, fold)
            for m in methods:
                m.fit(ep, mesh, hier)
                pred = m.predict(torch.cat([ep.context_sites, ep.target_sites]))
                rows[m.name] += _fold_rows(list(pred), truths, obs_nodes, fold)
    per_method = {name: _role_summary(rs) for name, rs in rows.items()}
    electrodes = int(ep.observed.sum())
    return {
        "subjects": view.subjects,
        "electrodes": electrodes,
        "noise_std": spec.noise_std,
        "methods": per_method,
        "ceiling": _role_summary(ceiling),
        "folds": {**{name: _targets(rs) for name, rs in rows.items()}, "ceiling": _targets(ceiling)},
    }


def _fold_rows(pred: list[np.ndarray], truths: list[np.ndarray], observed: np.ndarray, fold: dict) -> list[dict]:
    """Metrics of each sequence of a fold (the context ones, then the left-out target) at the ``observed`` nodes."""
    rows = []
    for j, (p, t) in enumerate(zip(pred, truths, strict=True)):
        p, t = p[:, observed], t[:, observed]
        role = "target" if j == len(truths) - 1 else "context"
        rows.append(
            {**fold, "role": role, "mse": mse(p, t), "cc_spatial": spatial_cc(p, t), "cc_temporal": temporal_cc(p, t)}
        )
    return rows


def _targets(rows: list[dict]) -> list[dict]:
    """The target rows of a fold-by-fold list: one per fold."""
    return [r for r in rows if r["role"] == "target"]


def _role_summary(rows: list[dict]) -> dict:
    """Mean and std of each metric over the context and over the target rows."""
    return {
        role: {
            metric: {
                "mean": float(np.nanmean([r[metric] for r in rows if r["role"] == role])),
                "std": float(np.nanstd([r[metric] for r in rows if r["role"] == role])),
            }
            for metric in ("mse", "cc_spatial", "cc_temporal")
        }
        for role in ("context", "target")
    }


def _timing(view: StoreView, meta_report: EvalReport, pns_report: EvalReport, base_reports: dict) -> dict:
    subject = view.subjects[0]
    mesh = view.mesh(view.mesh_of[subject])
    solver = read_solver_settings(view.store)
    tissue, site = read_tissue(view.store, subject), view.sites(view.mesh_of[subject])[:1]
    sim = load_simulator()
    sim.simulate(mesh, tissue, site, solver)  # JIT warm-up
    t0 = time.perf_counter()
    sim.simulate(mesh, tissue, site, solver)
    rows = {"AP simulation (one site, 1 thread)": {"seconds": time.perf_counter() - t0}}
    rows["metaPNS generation (per simulation)"] = {"seconds": meta_report.timing["predict_s_per_sim"]}
    rows["metaPNS context embedding (per set)"] = {"seconds": meta_report.timing["fit_s"]}
    rows["PNS generation (per simulation)"] = {"seconds": pns_report.timing["predict_s_per_sim"]}
    for name, rep in base_reports.items():
        rows[f"{name} personalisation (per set)"] = {
            "seconds": rep.timing["fit_s"],
            "simulator calls": rep.timing["simulator_calls"],
        }
        rows[f"{name} prediction (per simulation)"] = {"seconds": rep.timing["predict_s_per_sim"]}
    return rows


def run_benchmark(cfg: BenchmarkConfig, progress=print, device: str = "cpu") -> dict[str, Any]:
    """Run everything of the module docstring, the neural models on ``device``; returns the benchmark.json numbers."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    placed = resolve_device(device)
    meta, meta_cfg, meta_ckpt = load_model(cfg.metapns, placed)
    pns, pns_cfg, _ = load_model(cfg.pns, placed)
    if not meta.conditioned or pns.conditioned:
        raise InputError("`metapns` must be a metaPNS checkpoint and `pns` a PNS checkpoint")
    view = StoreView(cfg.store, cache_dir=out / "hierarchies")
    if view.frames != meta.frames:
        raise InputError(f"{cfg.store} has {view.frames} frames per simulation, the models expect {meta.frames}")
    setting = EvalSetting.of(meta_cfg)
    test = list(meta_ckpt["splits"]["test"])
    neural = build_methods(NEURAL, MethodContext(models={"metaPNS": meta, "PNS": pns}))
    spec = EvalSpec(
        subjects=tuple(test),
        context=cfg.context,
        context_sets=cfg.context_sets,
        max_targets=cfg.max_targets,
        seed=cfg.seed,
    )
    step = lambda what: lambda i, n, s: progress(f"{what}: [{i}/{n}] {s}")  # noqa: E731
    results: dict[str, Any] = {"config": to_mapping(cfg), "test_subjects": test}

    reports = evaluate_methods(neural, view, test, spec, setting, step("Table 1"))
    results["table1_all_test"] = {name: _stats(r) for name, r in reports.items()}

    b = cfg.baselines
    base_methods = baseline_methods(cfg, read_solver_settings(view.store), view.times)
    subset = test[: b.subjects]
    bspec = replace(spec, subjects=tuple(subset), context_sets=b.context_sets, max_targets=b.max_targets)
    examples: dict[str, dict] = {}
    base_reports = evaluate_methods(neural + base_methods, view, subset, bspec, setting, step("baselines"), examples)
    results["table1_baseline_subset"] = {name: _stats(r) for name, r in base_reports.items()}

    curves: dict[str, dict] = {m.name: {} for m in neural}
    for k in cfg.context_sizes:
        kspec = replace(spec, context=(k, k), context_sets=cfg.curve_sets, max_targets=cfg.curve_targets)
        for name, r in evaluate_methods(neural, view, test, kspec, setting).items():
            curves[name][str(k)] = r.overall["target"]
        progress(f"context size {k}: done")
    results["fig3"] = curves

    results["timing"] = _timing(view, reports["metaPNS"], reports["PNS"], {n: base_reports[n] for n in b.methods})
    results["calibration"] = calibration(meta, view, test[: cfg.calibration_subjects], cfg, setting)
    results["maps"] = subset[: cfg.maps]
    if cfg.real_data.store:
        real_setting = real_data_setting(cfg, setting)
        results["real_data"] = real_data(neural, real_setting, cfg)
        real_view = StoreView(cfg.real_data.store)
        real_solver = read_solver_settings(real_view.store)
        real_base = baseline_methods(cfg, real_solver, real_view.times)
        if real_base and cfg.real_data.baseline_folds:
            progress("real data: baselines")
            results["real_data_baseline_subset"] = real_data(
                neural + real_base, real_setting, cfg, cfg.real_data.baseline_folds
            )
    write_report(results, out, view, examples, NOISE_DRAWS)
    return results
