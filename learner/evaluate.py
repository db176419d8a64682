"""Evaluation of a trained surrogate on held-out subjects: MSE, CC, DC and activation-time error.

For each subject, ``context_sets`` context sets are drawn (sizes uniform in
``context``); the surrogate is personalised on each (c = mean of p(c | Y)) and
predicts both its context (fit) and the subject's other simulations (targets,
prediction). Metrics are per sequence (``learner.metrics``), summarised per
subject and overall for each role.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from shared.errors import InputError
from shared.units import MS_PER_TIME_UNIT

from learner.data.episodes import load_episode
from learner.metrics import METRIC_NAMES, activation_times, sequence_metrics, summarize
from learner.store_view import StoreView
from learner.train.trainer import load_model

__all__ = ["EvalSpec", "EvalReport", "evaluate", "default_dc_frame"]


def default_dc_frame(frames: int) -> int:
    """The late frame of the Dice score: after full activation, before repolarisation (~55% of the window)."""
    return (11 * frames) // 20


@dataclass(frozen=True)
class EvalSpec:
    """What to evaluate on (defaults: the checkpoint's test split, 3 context sets of 1-5 per subject)."""

    subjects: tuple[str, ...] | str = "test"  # a split name of the checkpoint, or explicit subject ids
    context: tuple[int, int] = (1, 5)
    context_sets: int = 3
    max_targets: int = 40  # targets per context set (0 = every other simulation of the subject)
    observe: str | None = None  # None: the training observation set
    noise_std: float | None = None  # None: the training noise
    seed: int = 0
    dc_frame: int | None = None  # None: default_dc_frame(T)
    batch: int = 16  # sites generated per forward pass


@dataclass
class EvalReport:
    """Per-sequence rows, summaries and timings of one evaluation."""

    model: str
    rows: list[dict] = field(default_factory=list)
    overall: dict = field(default_factory=dict)  # role -> metric -> {mean, std, n}
    per_subject: dict = field(default_factory=dict)  # subject -> role -> metric -> {...}
    by_context_size: dict = field(default_factory=dict)  # K -> role -> metric -> {...}
    timing: dict = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1, default=float)

    def to_markdown(self) -> str:
        """Overall and per-subject tables."""
        head = "| role | " + " | ".join(METRIC_NAMES) + " |\n|---|" + "---|" * len(METRIC_NAMES) + "\n"
        def fmt(stats: dict) -> str:  # noqa: E306
            return " | ".join(f"{stats[m]['mean']:.3g} ± {stats[m]['std']:.2g}" if m in stats else "-"
                              for m in METRIC_NAMES)  # fmt: skip
        lines = [f"## {self.model}: overall\n", head]
        lines += [f"| {role} | {fmt(s)} |\n" for role, s in self.overall.items()]
        lines += ["\n### per subject\n", "| subject | role | " + " | ".join(METRIC_NAMES) + " |\n",
                  "|---|---|" + "---|" * len(METRIC_NAMES) + "\n"]  # fmt: skip
        for subject, roles in self.per_subject.items():
            lines += [f"| {subject} | {role} | {fmt(s)} |\n" for role, s in roles.items()]
        t = self.timing
        lines.append(f"\nGeneration {1000 * t.get('generate_s_per_sim', float('nan')):.1f} ms per simulation, "
                     f"context embedding {1000 * t.get('embed_s', float('nan')):.1f} ms per set (CPU).\n")  # fmt: skip
        return "".join(lines)

    def write(self, folder: str | Path, stem: str = "evaluation") -> tuple[Path, Path]:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        js, md = folder / f"{stem}.json", folder / f"{stem}.md"
        js.write_text(self.to_json())
        md.write_text(self.to_markdown())
        return js, md


def _subjects(spec: EvalSpec, ckpt: dict, view: StoreView) -> list[str]:
    if isinstance(spec.subjects, str):
        if spec.subjects not in ckpt["splits"]:
            raise InputError(f"unknown split {spec.subjects!r}; the checkpoint has {sorted(ckpt['splits'])}")
        subjects = list(ckpt["splits"][spec.subjects])
    else:
        subjects = list(spec.subjects)
    for s in subjects:
        view.check_subject(s)
    if not subjects:
        raise InputError(f"no subjects to evaluate in {spec.subjects!r}")
    return subjects


def evaluate(checkpoint: str | Path, store: str | Path, spec: EvalSpec = EvalSpec(), progress=None) -> EvalReport:
    """Evaluate ``checkpoint`` on ``store`` (see :class:`EvalSpec`)."""
    model, config, ckpt = load_model(checkpoint)
    view = StoreView(store, cache_dir=Path(checkpoint).parent / "hierarchies")
    if view.frames != model.frames:
        raise InputError(f"{store} has {view.frames} frames per simulation, the model expects {model.frames}")
    lo, hi = spec.context
    if lo < 1 or hi < lo:
        raise InputError(f"context sizes must satisfy 1 <= min <= max, got {spec.context}")
    observe = spec.observe or config.data.episodes.observe
    noise = config.data.episodes.noise_std if spec.noise_std is None else spec.noise_std
    dc_frame = default_dc_frame(view.frames) if spec.dc_frame is None else spec.dc_frame
    times = view.times
    report = EvalReport(model=config.model.kind)
    embed_s, gen_s, gen_n = [], 0.0, 0
    subjects = _subjects(spec, ckpt, view)
    for si, subject in enumerate(subjects):
        mesh_id = view.mesh_of[subject]
        n_sites = len(view.sites(mesh_id))
        hier = view.hierarchy(mesh_id, config.model.levels, config.model.coarsest)
        for r in range(spec.context_sets):
            rng = np.random.default_rng([spec.seed, si, r])
            k = int(rng.integers(lo, hi + 1))
            if k >= n_sites:
                raise InputError(f"subject {subject!r} has {n_sites} simulations: too few for a context of {k}")
            perm = rng.permutation(n_sites)
            rest = perm[k:] if spec.max_targets <= 0 else perm[k : k + spec.max_targets]
            ep = load_episode(view.store, subject, perm[:k], np.sort(rest), observe, noise, rng)
            with torch.no_grad():
                c = None
                if model.conditioned:
                    t0 = time.perf_counter()
                    c = model.embed(ep.context_obs, ep.observed, hier).mu
                    embed_s.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                sites = torch.cat([ep.context_sites, ep.target_sites])
                pred = torch.cat([model.generate(sites[i : i + spec.batch], hier, c)
                                  for i in range(0, len(sites), spec.batch)]).numpy()  # fmt: skip
                gen_s, gen_n = gen_s + time.perf_counter() - t0, gen_n + len(sites)
            truth = torch.cat([ep.context_u, ep.target_u]).numpy()
            for j in range(len(sites)):
                # the truth's activation from its own frames, like the prediction's: no frame-rate bias
                true_act = activation_times(truth[j], times)
                m = sequence_metrics(pred[j], truth[j], true_act, times, dc_frame)
                report.rows.append({"subject": subject, "set": r, "context_size": k,
                                    "role": "context" if j < k else "target", "site": int(sites[j]), **m})  # fmt: skip
        if progress is not None:
            progress(si + 1, len(subjects), subject)
    _summarise(report)
    report.timing = {
        "embed_s": float(np.mean(embed_s)) if embed_s else float("nan"),
        "generate_s_per_sim": gen_s / max(gen_n, 1),
        "ms_per_time_unit": MS_PER_TIME_UNIT,
        "dc_frame": dc_frame,
    }
    return report


def _summarise(report: EvalReport) -> None:
    metric_rows = lambda rows: [{m: r[m] for m in METRIC_NAMES} for r in rows]  # noqa: E731
    for role in ("context", "target"):
        rows = [r for r in report.rows if r["role"] == role]
        report.overall[role] = summarize(metric_rows(rows))
        for r in rows:
            report.per_subject.setdefault(r["subject"], {})
        for subject in report.per_subject:
            sub = [r for r in rows if r["subject"] == subject]
            report.per_subject[subject][role] = summarize(metric_rows(sub))
        for k in sorted({r["context_size"] for r in rows}):
            sub = [r for r in rows if r["context_size"] == k]
            report.by_context_size.setdefault(str(k), {})[role] = summarize(metric_rows(sub))
