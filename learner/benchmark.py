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

import json
import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from learner.baselines import FSBO, VAEBO, PersonalisationBaseline
from learner.data.episodes import Episode, load_episode
from learner.evaluate import EvalReport, EvalSpec, Method, NeuralMethod, evaluate_methods
from learner.graph.hierarchy import MeshHierarchy
from learner.metrics import METRIC_NAMES, activation_times, mse, spatial_cc, temporal_cc
from learner.models.site_evidence import SiteEvidence
from learner.personalize import Observations
from learner.plot import plot_activation_panels, plot_context_curves
from learner.pretrained import resolve_reference
from learner.runtime import on_device, resolve_device
from learner.store_view import StoreView
from learner.train.trainer import load_model
from shared.config import from_mapping, load_toml, to_mapping
from shared.errors import ConfigError, InputError
from shared.location import resolve_location
from shared.mesh import Mesh
from shared.observation import Observation, gaussian_noise
from shared.reader import read_solver_settings, read_tissue
from shared.simulator import load_simulator
from shared.units import MS_PER_TIME_UNIT

__all__ = [
    "BaselineSpec",
    "RealDataSpec",
    "BenchmarkConfig",
    "load_benchmark_config",
    "BaselineMethod",
    "baseline_methods",
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


class BaselineMethod(Method):
    """A BO baseline behind the :class:`~learner.evaluate.Method` interface (simulates its predictions)."""

    def __init__(self, baseline: PersonalisationBaseline, solver: dict, times: np.ndarray) -> None:
        self.baseline, self.solver, self.times, self.name = baseline, solver, times, baseline.name

    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        obs = Observations(
            mesh,
            episode.context_sites.numpy(),
            episode.context_obs.numpy(),
            episode.observed.numpy(),
            self.times,
            episode.subject_id,
        )
        result = self.baseline.fit(obs, self.solver)
        return {"fit_s": result.seconds, "calls": float(result.calls)}

    def predict(self, sites: Tensor) -> np.ndarray:
        return self.baseline.predict(sites.numpy())


def baseline_methods(
    cfg: BenchmarkConfig, solver: dict, times: np.ndarray, names: tuple[str, ...] | None = None
) -> list[BaselineMethod]:
    """Fresh BO baselines ``names`` (default ``cfg.baselines.methods``) with the config's budget, regions and seed.

    ``solver`` and ``times`` are those of the store they will be fitted on.
    """
    b = cfg.baselines
    make = {
        "fs-bo": lambda: FSBO(regions=b.regions, budget=b.budget, seed=cfg.seed),
        "vae-bo": lambda: VAEBO(budget=b.budget, seed=cfg.seed),
    }
    names = b.methods if names is None else names
    unknown = sorted(set(names) - set(make))
    if unknown:
        raise ConfigError(f"unknown baseline(s) {unknown}; choose from {sorted(make)}")
    return [BaselineMethod(make[name](), solver, times) for name in names]


def _stats(report: EvalReport) -> dict:
    return {"overall": report.overall, "by_context_size": report.by_context_size, "timing": report.timing}


def table1(results: dict[str, dict], title: str) -> str:
    """Markdown Table 1: context | target, mean ± std of each metric per method."""
    cols = [m for m in METRIC_NAMES if m != "act_mismatch"]
    head = "| method | " + " | ".join(f"context {m}" for m in cols) + " | " + " | ".join(f"target {m}" for m in cols)
    lines = [f"### {title}\n", head + " |\n", "|---|" + "---|" * (2 * len(cols)) + "\n"]
    for name, res in results.items():
        cells = [_cell(res["overall"].get(role, {}).get(m)) for role in ("context", "target") for m in cols]
        lines.append(f"| {name} | " + " | ".join(cells) + " |\n")
    return "".join(lines)


def _cell(stat: dict | None) -> str:
    if not stat or not np.isfinite(stat["mean"]):
        return "-"
    m, s = stat["mean"], stat["std"]
    return f"{m:.2e} ± {s:.1e}" if abs(m) < 1e-2 else f"{m:.3f} ± {s:.3f}"


NOISE_DRAWS = 10  # Gaussian model-error draws per sample of c in the calibration band


def calibration(
    model, view: StoreView, subjects: list[str], cfg: BenchmarkConfig, observe: str, levels: int, coarsest: int
) -> dict:
    """How often target values fall inside the 5-95% band of two predictive distributions.

    * ``c`` only: samples of ``c ~ p(c | Y)`` through the generator (the
      model's epistemic spread about the subject);
    * ``c`` + noise: the same draws plus Gaussian model error ``N(0, s^2)``,
      with ``s`` the root-mean-square residual of the draws on the context's
      observed values: the subject's own misfit, known without the targets.
      ``NOISE_DRAWS`` noise draws per ``c``.
    """
    tally = {"noise": np.zeros(2), "c": np.zeros(2)}  # values inside the band, summed band width
    n, device = 0, next(model.parameters()).device
    g = torch.Generator().manual_seed(cfg.seed)
    for si, subject in enumerate(subjects):
        mesh_id = view.mesh_of[subject]
        hier = on_device(view.hierarchy(mesh_id, levels, coarsest), device)
        rng = np.random.default_rng([cfg.seed, si, 99])
        perm = rng.permutation(len(view.sites(mesh_id)))
        ep = load_episode(view.store, subject, perm[:3], np.sort(perm[3:8]), observe)
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


def real_data(methods: list[Method], levels: int, coarsest: int, cfg: BenchmarkConfig, folds: int = 0) -> dict:
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
    for the ``ceiling``: where the error is.
    """
    spec = cfg.real_data
    view, observation = StoreView(spec.store), Observation(spec.observe, spec.noise_std)
    for m in methods:
        if isinstance(m, NeuralMethod) and view.frames != m.model.frames:
            raise InputError(f"{spec.store} has {view.frames} frames per simulation, {m.name} expects {m.model.frames}")
    rows: dict[str, list[dict]] = {m.name: [] for m in methods}
    ceiling: list[dict] = []
    for si, subject in enumerate(view.subjects):
        mesh_id = view.mesh_of[subject]
        mesh, hier = view.mesh(mesh_id), view.hierarchy(mesh_id, levels, coarsest)
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


def real_data_table(result: dict) -> str:
    """Markdown: one row per method of a :func:`real_data` result."""
    lines = [
        "| method | target mse | target cc_spatial | target cc_temporal | context cc_spatial |",
        "|---|---|---|---|---|",
    ]
    named = {**result["methods"], "noise-free truth (ceiling)": result["ceiling"]}
    for name, r in named.items():
        t, c = r["target"], r["context"]
        lines.append(
            f"| {name} | {_cell(t['mse'])} | {_cell(t['cc_spatial'])} | {_cell(t['cc_temporal'])} "
            f"| {_cell(c['cc_spatial'])} |"
        )
    return "\n".join(lines) + "\n"


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


def _maps_per_mesh(view: StoreView, rows: list, subjects: list[str], path: Path) -> list[Path]:
    """One figure per subject (``<stem>-<subject>.png``), drawn on that subject's own mesh."""
    paths = []
    for (title, cols), subject in zip(rows, subjects):
        p = path.with_name(f"{path.stem}-{subject}{path.suffix}")
        plot_activation_panels(view.mesh(view.mesh_of[subject]).points, [(title, cols)], p)
        paths.append(p)
    return paths


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
    levels, coarsest = meta_cfg.model.levels, meta_cfg.model.coarsest
    observe, noise = meta_cfg.data.episodes.primary_observe, meta_cfg.data.episodes.noise_std
    test = list(meta_ckpt["splits"]["test"])
    neural = [NeuralMethod(meta, "metaPNS"), NeuralMethod(pns, "PNS")]
    spec = EvalSpec(
        subjects=tuple(test),
        context=cfg.context,
        context_sets=cfg.context_sets,
        max_targets=cfg.max_targets,
        seed=cfg.seed,
    )
    step = lambda what: lambda i, n, s: progress(f"{what}: [{i}/{n}] {s}")  # noqa: E731
    results: dict[str, Any] = {"config": to_mapping(cfg), "test_subjects": test}

    reports = evaluate_methods(neural, view, test, spec, observe, noise, levels, coarsest, step("Table 1"))
    results["table1_all_test"] = {name: _stats(r) for name, r in reports.items()}

    b = cfg.baselines
    base_methods = baseline_methods(cfg, read_solver_settings(view.store), view.times)
    subset = test[: b.subjects]
    bspec = replace(spec, subjects=tuple(subset), context_sets=b.context_sets, max_targets=b.max_targets)
    examples: dict[str, dict] = {}
    base_reports = evaluate_methods(
        neural + base_methods, view, subset, bspec, observe, noise, levels, coarsest, step("baselines"), examples
    )
    results["table1_baseline_subset"] = {name: _stats(r) for name, r in base_reports.items()}

    curves: dict[str, dict] = {m.name: {} for m in neural}
    for k in cfg.context_sizes:
        kspec = replace(spec, context=(k, k), context_sets=cfg.curve_sets, max_targets=cfg.curve_targets)
        for name, r in evaluate_methods(neural, view, test, kspec, observe, noise, levels, coarsest).items():
            curves[name][str(k)] = r.overall["target"]
        progress(f"context size {k}: done")
    results["fig3"] = curves
    plot_context_curves(curves, out / "fig3_context.png")

    results["timing"] = _timing(view, reports["metaPNS"], reports["PNS"], {n: base_reports[n] for n in b.methods})
    results["calibration"] = calibration(meta, view, test[: cfg.calibration_subjects], cfg, observe, levels, coarsest)
    results["maps"] = subset[: cfg.maps]
    _maps_per_mesh(
        view,
        [_map_row(view, examples[s], [m.name for m in neural + base_methods], s) for s in results["maps"]],
        results["maps"],
        out / "activation_maps.png",
    )
    if cfg.real_data.store:
        results["real_data"] = real_data(neural, levels, coarsest, cfg)
        real_view = StoreView(cfg.real_data.store)
        real_solver = read_solver_settings(real_view.store)
        real_base = baseline_methods(cfg, real_solver, real_view.times)
        if real_base and cfg.real_data.baseline_folds:
            progress("real data: baselines")
            results["real_data_baseline_subset"] = real_data(
                neural + real_base, levels, coarsest, cfg, cfg.real_data.baseline_folds
            )
    _write(results, out)
    return results


def _map_row(view: StoreView, example: dict, methods: list[str], subject: str) -> tuple[str, list]:
    """Activation-time maps (ms) of the truth and each method on one target, from the baseline table's run."""
    to_ms = lambda u: activation_times(u, view.times) * MS_PER_TIME_UNIT  # noqa: E731
    cols = [("truth", to_ms(example["truth"]))] + [(name, to_ms(example[name])) for name in methods]
    return (f"{subject}, site {example['site']}", cols)


def _write(results: dict, out: Path) -> None:
    maps = "".join(f"![activation maps](activation_maps-{s}.png)\n" for s in results["maps"])
    md = [
        "# Benchmark\n\n",
        table1(
            results["table1_all_test"], f"Table 1: all {len(results['test_subjects'])} test subjects (metaPNS, PNS)"
        ),
        "\n",
        table1(results["table1_baseline_subset"], "Table 1: the baseline subset, same context sets for every method"),
        "\n![accuracy vs context size](fig3_context.png)\n\n### Timing (CPU)\n\n| step | seconds | simulator calls |\n"
        "|---|---|---|\n",
    ]
    timing = [
        f"| {name} | {row['seconds']:.4g} | {row.get('simulator calls', '')} |\n"
        for name, row in results["timing"].items()
    ]
    md += timing
    (out / "timing.md").write_text("| step | seconds | simulator calls |\n|---|---|---|\n" + "".join(timing))
    c = results["calibration"]
    md.append(
        f"\n### Uncertainty\n\n{c['samples']} draws of c ~ p(c | Y), each with {NOISE_DRAWS} draws of the "
        f"subject's context misfit N(0, s^2): the truth lies inside the 5-95% band for "
        f"{100 * c['coverage_90']:.1f}% of target values (ideal 90%; mean band width "
        f"{c['mean_band_width']:.3f}). From c alone: {100 * c['coverage_90_c_only']:.1f}% (width "
        f"{c['mean_band_width_c_only']:.3f}).\n"
    )
    md.append(f"\n### Activation maps (truth vs predictions, one target site)\n\n{maps}")
    if "real_data" in results:
        r = results["real_data"]
        sites = results["config"]["real_data"]["sites"]
        md.append(
            f"\n### Real-data emulation\n\nUnseen geometry {', '.join(r['subjects'])}, {r['electrodes']} sock "
            f"electrodes, noise {r['noise_std']}, each of {sites} pacing sites left out in turn:\n\n"
            + real_data_table(r)
        )
    if "real_data_baseline_subset" in results:
        folds = results["config"]["real_data"]["baseline_folds"]
        md.append(
            f"\nThe BO baselines on the first {folds} left-out site(s) of each subject, every method on the same "
            f"folds:\n\n" + real_data_table(results["real_data_baseline_subset"])
        )
    (out / "benchmark.md").write_text("".join(md))
    (out / "table1.md").write_text(
        table1(results["table1_all_test"], "all test subjects")
        + "\n"
        + table1(results["table1_baseline_subset"], "baseline subset")
    )
    (out / "benchmark.json").write_text(json.dumps(results, indent=1, default=float))
