"""Evaluation of a trained surrogate on held-out subjects: MSE, CC, DC and activation-time error.

For each subject, ``context_sets`` context sets are drawn (sizes uniform in
``context``); every method (:class:`Method`: metaPNS, PNS, the BO baselines)
is personalised on each - for metaPNS c = mean of p(c | Y), optionally refined on the
context (``EvalSpec.refine``) - and predicts both
its context (fit) and the subject's other simulations (targets, prediction),
the same sets for every method. Metrics are per sequence (``learner.metrics``), summarised per
subject and overall for each role.
"""

from __future__ import annotations

import json
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import Tensor

from learner.config import LearnerConfig
from learner.data.episodes import Episode, load_episode
from learner.graph.hierarchy import MeshHierarchy
from learner.metrics import METRIC_NAMES, activation_times, sequence_metrics, summarize
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import PNS
from learner.refine import Refinement, ecg_leads, observed_nodes, recorded_values, refine_context
from learner.runtime import on_device, resolve_device
from learner.store_view import StoreView
from learner.train.trainer import load_model
from shared.errors import InputError
from shared.mesh import Mesh
from shared.observation import Observation, check_noise_std, check_observation_set
from shared.units import MS_PER_TIME_UNIT

__all__ = [
    "EvalSpec",
    "EvalSetting",
    "EvalReport",
    "Method",
    "NeuralMethod",
    "EnsembleMethod",
    "load_method",
    "evaluate_methods",
    "evaluate",
    "default_dc_frame",
]


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
    observe: str | None = None  # None: the training observation set (the first, for a mixture); "ecg": 12-lead ECGs
    noise_std: float | None = None  # None: the training noise (with "ecg": a share of the largest lead value)
    seed: int = 0
    dc_frame: int | None = None  # None: default_dc_frame(T)
    batch: int = 16  # sites generated per forward pass
    refine: Refinement = Refinement()  # steps > 0: refine c on each context set (learner.refine)

    def __post_init__(self) -> None:
        if self.observe is not None and self.observe != ECG:
            check_observation_set(self.observe)
        if self.noise_std is not None:
            check_noise_std(self.noise_std)


#: The observation that records each context set as the 12-lead ECGs of its simulations (:mod:`learner.ecg`).
ECG = "ecg"


@dataclass(frozen=True)
class EvalSetting:
    """How every method sees a subject: the observation (node set, noise) and the mesh hierarchy of the model;
    with ``ecg_noise``, the context recorded as 12-lead ECGs with that noise share instead."""

    observation: Observation
    levels: int
    coarsest: int
    working_nodes: int | None = None
    ecg_noise: float | None = None

    @classmethod
    def of(cls, config: LearnerConfig, observe: str | None = None, noise_std: float | None = None) -> EvalSetting:
        """The setting of a model trained with ``config``: its first observation set and noise unless given."""
        episodes, model = config.data.episodes, config.model
        if observe == ECG:
            ecg_noise = episodes.ecg_noise if noise_std is None else noise_std
            return cls(
                Observation(episodes.primary_observe), model.levels, model.coarsest, model.working_nodes, ecg_noise
            )
        observation = Observation(
            observe or episodes.primary_observe, episodes.noise_std if noise_std is None else noise_std
        )
        return cls(observation, model.levels, model.coarsest, model.working_nodes)

    def hierarchy(self, view: StoreView, mesh_id: str) -> MeshHierarchy:
        """The mesh hierarchy of ``mesh_id`` that the model works on."""
        return view.hierarchy(mesh_id, self.levels, self.coarsest, self.working_nodes)

    def episode(
        self, view: StoreView, subject: str, context: ArrayLike, targets: ArrayLike, rng: np.random.Generator | None
    ) -> Episode:
        """The episode of ``subject`` with these context and target rows, observed in this setting."""
        obs = self.observation
        return load_episode(view.store, subject, context, targets, obs.nodes, obs.noise_std, rng, self.ecg_noise)


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
            return " | ".join(
                f"{stats[m]['mean']:.3g} ± {stats[m]['std']:.2g}" if m in stats else "-" for m in METRIC_NAMES
            )

        lines = [f"## {self.model}: overall\n", head]
        lines += [f"| {role} | {fmt(s)} |\n" for role, s in self.overall.items()]
        lines += [
            "\n### per subject\n",
            "| subject | role | " + " | ".join(METRIC_NAMES) + " |\n",
            "|---|---|" + "---|" * len(METRIC_NAMES) + "\n",
        ]
        for subject, roles in self.per_subject.items():
            lines += [f"| {subject} | {role} | {fmt(s)} |\n" for role, s in roles.items()]
        t = self.timing
        fit_ms, device = 1000 * t.get("fit_s", float("nan")), t.get("device", "cpu")
        lines.append(
            f"\nPrediction {1000 * t.get('predict_s_per_sim', float('nan')):.1f} ms per simulation, "
            f"personalisation {fit_ms:.1f} ms per context set ({device}).\n"
        )
        return "".join(lines)

    def write(self, folder: str | Path, stem: str = "evaluation") -> tuple[Path, Path]:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        js, md = folder / f"{stem}.json", folder / f"{stem}.md"
        js.write_text(self.to_json())
        md.write_text(self.to_markdown())
        return js, md


class Method(ABC):
    """A way to personalise on a context set and then predict any stimulation site of that subject."""

    name: str = "method"

    @abstractmethod
    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        """Personalise on ``episode``'s context; returns what it cost (``fit_s``, optional ``calls``)."""

    @abstractmethod
    def predict(self, sites: Tensor) -> np.ndarray:
        """Sequences ``(S, T, N)`` for stimulation node ids ``sites`` of the fitted subject."""


class NeuralMethod(Method):
    """metaPNS (c = mean of p(c | Y), or refined on the context: ``refine``) or PNS (no c) as a :class:`Method`."""

    def __init__(self, model: PNS, name: str, batch: int = 16, refine: Refinement = Refinement()) -> None:
        self.model, self.name, self.batch, self.refine = model.eval(), name, batch, refine
        self.device = next(model.parameters()).device
        self._c: Tensor | None = None
        self._evidence: SiteEvidence | None = None
        self._hier: MeshHierarchy | None = None

    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        self._hier, self._c, self._evidence = on_device(hierarchy, self.device), None, None
        if not self.model.conditioned:
            return {"fit_s": 0.0}
        t0 = time.perf_counter()
        ep = episode.to(self.device)
        if ep.context_ecg is None:
            with torch.no_grad():
                posterior = self.model.embed(ep.context_obs, ep.observed, self._hier, ep.context_recorded)
            self._evidence = SiteEvidence.of(ep)
            target = recorded_values(ep.context_obs, ep.observed, ep.context_recorded)
            record = observed_nodes(ep.observed)
        else:
            with torch.no_grad():
                posterior = self.model.embed_ecg(ep.context_ecg, ep.lead_field, ep.context_sites, self._hier)
            scale = float(ep.context_ecg.abs().max())
            target, record = ep.context_ecg / scale, ecg_leads(ep.lead_field, scale)
        self._c = posterior.mu
        if self.refine.steps:
            self._c, _, _ = refine_context(
                self.model, posterior, target, record, ep.context_sites, self._hier, self._evidence, self.refine
            )
        return {"fit_s": time.perf_counter() - t0}

    def predict(self, sites: Tensor) -> np.ndarray:
        sites = sites.to(self.device)
        with torch.no_grad():
            parts = [
                self.model.generate(sites[i : i + self.batch], self._hier, self._c, evidence=self._evidence)
                for i in range(0, len(sites), self.batch)
            ]
        return torch.cat(parts).cpu().numpy()


class EnsembleMethod(Method):
    """Several methods fitted on the same context set, their predictions averaged: a deep ensemble.

    Surrogates trained from other seeds or on other data place a wave
    differently where the training hearts say little about a new one; the mean of
    their predictions errs less than each of them on average (Lakshminarayanan
    et al. 2017, *Simple and Scalable Predictive Uncertainty Estimation using
    Deep Ensembles*). Fitting and predicting cost the sum of the members'.
    """

    def __init__(self, members: Sequence[Method], name: str) -> None:
        if len(members) < 2:
            raise InputError(f"an ensemble needs at least 2 members, got {len(members)}")
        self.members, self.name = list(members), name
        self.device = getattr(self.members[0], "device", "cpu")

    def fit(self, episode: Episode, mesh: Mesh, hierarchy: MeshHierarchy) -> dict[str, float]:
        costs = [m.fit(episode, mesh, hierarchy) for m in self.members]
        return {"fit_s": sum(c["fit_s"] for c in costs), "calls": sum(c.get("calls", 0.0) for c in costs)}

    def predict(self, sites: Tensor) -> np.ndarray:
        return np.mean([m.predict(sites) for m in self.members], axis=0)


#: What the members of an ensemble must share: the sequences they predict and the mesh hierarchy they run on.
_ENSEMBLE_KEYS = ("kind", "levels", "coarsest")


def load_method(
    checkpoints: str | Path | Sequence[str | Path],
    device: torch.device | str = "cpu",
    batch: int = 16,
    refine: Refinement = Refinement(),
) -> tuple[Method, LearnerConfig, list[dict]]:
    """A :class:`NeuralMethod` for one checkpoint, an :class:`EnsembleMethod` of several.

    Returns the method, the first checkpoint's config (observation set and
    noise of the evaluation) and every checkpoint dict. Ensemble members must
    agree on the model kind, the frames and the mesh hierarchy (``levels``,
    ``coarsest``); anything else (seed, data, widths) may differ.
    """
    paths = [checkpoints] if isinstance(checkpoints, str | Path) else list(checkpoints)
    if not paths:
        raise InputError("no checkpoint to evaluate")
    loaded = [load_model(p, device) for p in paths]
    (model, config, _), methods = loaded[0], []
    for path, (member, member_config, _) in zip(paths, loaded, strict=True):
        for key in _ENSEMBLE_KEYS:
            if getattr(member_config.model, key) != getattr(config.model, key):
                raise InputError(
                    f"{path}: model.{key} = {getattr(member_config.model, key)!r}, but {paths[0]} has "
                    f"{getattr(config.model, key)!r}; ensemble members must agree on {', '.join(_ENSEMBLE_KEYS)}"
                )
        if member.frames != model.frames:
            raise InputError(f"{path} predicts {member.frames} frames, {paths[0]} {model.frames}")
        methods.append(NeuralMethod(member, config.model.kind, batch, refine))
    method = (
        methods[0] if len(methods) == 1 else EnsembleMethod(methods, f"ensemble of {len(methods)} {config.model.kind}")
    )
    return method, config, [ckpt for _, _, ckpt in loaded]


def _ensemble_splits(paths: Sequence[str | Path], ckpts: list[dict], split: str) -> dict:
    """The splits of the first checkpoint, after checking that every member has the same ``split``."""
    first = ckpts[0].get("splits", {})
    for path, ckpt in zip(paths[1:], ckpts[1:], strict=True):
        if ckpt.get("splits", {}).get(split) != first.get(split):
            raise InputError(
                f"{path} has another {split!r} split than {paths[0]}: a subject one member holds out "
                "may be in another's training; evaluate an ensemble on a split its members share"
            )
    return first


def _subjects(spec: EvalSpec, splits: dict, view: StoreView) -> list[str]:
    if isinstance(spec.subjects, str):
        if spec.subjects not in splits:
            raise InputError(f"unknown split {spec.subjects!r}; the checkpoint has {sorted(splits)}")
        subjects = list(splits[spec.subjects])
    else:
        subjects = list(spec.subjects)
    for s in subjects:
        view.check_subject(s)
    if not subjects:
        raise InputError(f"no subjects to evaluate in {spec.subjects!r}")
    return subjects


def evaluate_methods(
    methods: list[Method],
    view: StoreView,
    subjects: list[str],
    spec: EvalSpec,
    setting: EvalSetting,
    progress=None,
    examples: dict[str, dict] | None = None,
) -> dict[str, EvalReport]:
    """Every method on the same context sets and targets, observed in ``setting``; one :class:`EvalReport` per method.

    ``examples``, when given, receives per subject the first target of the
    first context set: ``{"site", "truth", <method name>: prediction}`` (T, N)
    arrays, for figures drawn without refitting any method.
    """
    lo, hi = spec.context
    if lo < 1 or hi < lo:
        raise InputError(f"context sizes must satisfy 1 <= min <= max, got {spec.context}")
    dc_frame = default_dc_frame(view.frames) if spec.dc_frame is None else spec.dc_frame
    times = view.times
    reports = {m.name: EvalReport(model=m.name) for m in methods}
    costs: dict[str, dict[str, list[float]]] = {m.name: {"fit_s": [], "calls": [], "predict_s": []} for m in methods}
    n_predicted = 0
    for si, subject in enumerate(subjects):
        mesh_id = view.mesh_of[subject]
        n_sites = len(view.sites(mesh_id))
        mesh, hier = view.mesh(mesh_id), setting.hierarchy(view, mesh_id)
        for r in range(spec.context_sets):
            rng = np.random.default_rng([spec.seed, si, r])
            k = int(rng.integers(lo, hi + 1))
            if k >= n_sites:
                raise InputError(f"subject {subject!r} has {n_sites} simulations: too few for a context of {k}")
            perm = rng.permutation(n_sites)
            rest = perm[k:] if spec.max_targets <= 0 else perm[k : k + spec.max_targets]
            ep = setting.episode(view, subject, perm[:k], np.sort(rest), rng)
            sites = torch.cat([ep.context_sites, ep.target_sites])
            truth = torch.cat([ep.context_u, ep.target_u]).numpy()
            # the truth's activation from its own frames, like the prediction's: no frame-rate bias
            true_act = [activation_times(truth[j], times) for j in range(len(sites))]
            n_predicted += len(sites)
            for m in methods:
                cost = m.fit(ep, mesh, hier)
                t0 = time.perf_counter()
                pred = m.predict(sites)
                costs[m.name]["predict_s"].append(time.perf_counter() - t0)
                costs[m.name]["fit_s"].append(cost["fit_s"])
                costs[m.name]["calls"].append(cost.get("calls", 0.0))
                if examples is not None and r == 0 and len(sites) > k:
                    examples.setdefault(subject, {"site": int(sites[k]), "truth": truth[k]})[m.name] = pred[k]
                for j in range(len(sites)):
                    metrics = sequence_metrics(pred[j], truth[j], true_act[j], times, dc_frame)
                    reports[m.name].rows.append(
                        {
                            "subject": subject,
                            "set": r,
                            "context_size": k,
                            "role": "context" if j < k else "target",
                            "site": int(sites[j]),
                            **metrics,
                        }
                    )
        if progress is not None:
            progress(si + 1, len(subjects), subject)
    for m in methods:
        report, c = reports[m.name], costs[m.name]
        _summarise(report)
        report.timing = {
            "fit_s": float(np.mean(c["fit_s"])),
            "simulator_calls": float(np.mean(c["calls"])),
            "predict_s_per_sim": float(np.sum(c["predict_s"]) / max(n_predicted, 1)),
            "ms_per_time_unit": MS_PER_TIME_UNIT,
            "dc_frame": dc_frame,
            "device": str(getattr(m, "device", "cpu")),
        }
    return reports


def evaluate(
    checkpoint: str | Path | Sequence[str | Path],
    store: str | Path,
    spec: EvalSpec = EvalSpec(),
    progress=None,
    device: str = "cpu",
) -> EvalReport:
    """Evaluate ``checkpoint`` on ``store`` (see :class:`EvalSpec`), the model on ``device`` (``auto``, ``cuda``...).

    Several checkpoints are evaluated as one ensemble (:func:`load_method`); a
    split named in ``spec.subjects`` must then be the same in each of them.
    """
    paths = [checkpoint] if isinstance(checkpoint, str | Path) else list(checkpoint)
    method, config, ckpts = load_method(paths, resolve_device(device), spec.batch, spec.refine)
    first = Path(paths[0])  # a shipped model's name is no file: its hierarchies are not cached
    view = StoreView(store, cache_dir=first.parent / "hierarchies" if first.is_file() else None)
    if view.frames != ckpts[0]["frames"]:
        raise InputError(f"{store} has {view.frames} frames per simulation, the model expects {ckpts[0]['frames']}")
    setting = EvalSetting.of(config, spec.observe, spec.noise_std)
    splits = ckpts[0].get("splits", {})
    if len(paths) > 1 and isinstance(spec.subjects, str):
        splits = _ensemble_splits(paths, ckpts, spec.subjects)
    reports = evaluate_methods([method], view, _subjects(spec, splits, view), spec, setting, progress)
    return reports[method.name]


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
