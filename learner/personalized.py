"""A personalised heart: a trained metaPNS fitted to one subject's recordings, predicting new pacing sites.

:func:`personalize` embeds a subject's context set (:class:`~learner.observations.Observations`)
once and returns a :class:`PersonalizedHeart`, which keeps everything a
prediction needs in memory: the model on its device, the context embedding
``c``, the mesh and its graph hierarchy (with the working-graph map of a model
that has one, :mod:`learner.graph.working`), and the geodesic distance rows of
the sites already asked for. :meth:`PersonalizedHeart.predict` then costs one
pass of the generator. A heart saved to a file (:meth:`PersonalizedHeart.save`)
holds the same, hierarchy included, so a new process loads it without building
anything.

Recordings whose stimulus started no wave (:mod:`shared.capture`) are left out
of the context set, each named in :attr:`PersonalizedHeart.dropped`, and a
prediction says which of its sites start none (:attr:`Prediction.started_wave`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from learner.activation_maps import ApTemplate, template_from_store
from learner.checkpoint import DIGESTS, load_checkpoint, save_checkpoint
from learner.config import LearnerConfig, config_from_mapping
from learner.ecg import LeadField
from learner.graph.hierarchy import MeshHierarchy, hierarchy_for_mesh
from learner.metrics import activation_times
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS, Posterior, build_model
from learner.observations import Observations
from learner.refine import Refinement, ecg_leads, observed_nodes, recorded_values, refine_context
from learner.runtime import resolve_device
from learner.store_view import StoreView
from learner.tissue_estimate import TISSUE_SAMPLES, TissueEstimate, estimate_tissue
from learner.train.trainer import load_model
from shared.capture import recorded_fraction, started_wave
from shared.ecg import LEADS
from shared.errors import InputError
from shared.mesh import Mesh
from shared.sites import SITE_TOLERANCE, SiteLabels, nearest_nodes, refuse_repeated, region_nodes, site_names
from shared.units import MS_PER_TIME_UNIT, to_millivolts
from shared.vtk import write_time_series

__all__ = ["NoWaveWarning", "Prediction", "PersonalizedHeart", "personalize", "predict", "write_vtk", "plot_prediction"]


class NoWaveWarning(UserWarning):
    """Recordings left out of a context set because their stimulus started no wave."""


@dataclass
class Prediction:
    """Predicted sequences of a personalised heart at ``sites`` (mesh node ids).

    ``activated``: (S,) the share of the mesh's nodes each predicted sequence
    activates (``u`` reaches 0.5); :attr:`started_wave` reads it.
    """

    sites: np.ndarray  # (S,)
    u: np.ndarray  # (S, T, N) mean prediction
    times: np.ndarray  # (T,)
    mesh: Mesh
    spread: np.ndarray | None = None  # (S, T, N) std over samples of c, when samples > 1
    seconds: float = 0.0
    activated: np.ndarray = field(default_factory=lambda: np.zeros(0))
    activation_spread: np.ndarray | None = None  # (S, N) std of the activation time over samples (time units)
    ecg: np.ndarray | None = None  # (S, 12, T) mV: the predictions' 12-lead ECGs, for a heart personalised from ECGs

    @property
    def started_wave(self) -> np.ndarray:
        """(S,) whether the model predicts a propagating wave from each site (:mod:`shared.capture`)."""
        return started_wave(self.activated)

    @cached_property
    def activation(self) -> np.ndarray:
        """(S, N) predicted activation times in model time units (first crossing of ``u = 0.5``; NaN: never)."""
        return np.stack([activation_times(u, self.times) for u in self.u])

    def arrays(self) -> dict[str, np.ndarray]:
        """The prediction file's arrays (docs/formats.md): physical units, the mesh with them."""
        arrays = {
            "sites": self.sites,
            "site_xyz": self.mesh.points[self.sites],
            "times_ms": np.asarray(self.times, np.float64) * MS_PER_TIME_UNIT,
            "v_mv": to_millivolts(self.u).astype(np.float32),
            "activation_ms": (self.activation * MS_PER_TIME_UNIT).astype(np.float32),
            "activated_fraction": self.activated,
            "started_wave": self.started_wave,
            "points": self.mesh.points,
            "cells": self.mesh.cells,
        }
        if self.ecg is not None:
            arrays |= {"ecg_mv": self.ecg, "leads": np.array(LEADS), "ecg_times_ms": arrays["times_ms"]}
        if self.spread is not None:
            arrays["spread_mv"] = (100.0 * self.spread).astype(np.float32)
            arrays["activation_spread_ms"] = (self.activation_spread * MS_PER_TIME_UNIT).astype(np.float32)
        return arrays


class PersonalizedHeart:
    """A metaPNS personalised to one heart, with what its predictions need kept in memory (module docstring).

    Made by :func:`personalize` or read by :meth:`load`. ``dropped``: the
    recordings left out of the context set for showing no wave, as
    ``(node id, activated share of the observed nodes)``.
    """

    def __init__(
        self,
        model: MetaPNS,
        posterior: Posterior,
        hierarchy: MeshHierarchy,
        mesh: Mesh,
        times: np.ndarray,
        payload: dict,
        labels: SiteLabels | None = None,
        evidence: SiteEvidence | None = None,
    ) -> None:
        self.model, self.posterior, self.hierarchy = model, posterior, hierarchy
        self.mesh, self.times, self.labels, self.evidence = mesh, times, labels, evidence
        self._payload = payload  # what save() writes besides the arrays above
        self.dropped: list[tuple[int, float]] = [tuple(d) for d in payload.get("dropped", [])]

    @property
    def device(self) -> torch.device:
        return self.posterior.mu.device

    @property
    def lead_field(self) -> LeadField | None:
        """The mesh's lead field of a heart personalised from ECGs (its predictions' ECGs), else None."""
        if "lead_matrix" not in self._payload:
            return None
        return LeadField(self._payload["lead_matrix"], self._payload["lead_density"])

    @property
    def subject(self) -> str:
        return self._payload.get("subject", "")

    @property
    def embed_seconds(self) -> float:
        """Seconds the personalisation took (embedding, and refinement if any)."""
        return float(self._payload.get("embed_seconds", 0.0))

    @property
    def refine_steps_taken(self) -> int:
        """Refinement steps the held-out recordings chose (:func:`~learner.refine.refine_context`; 0: none)."""
        return int(self._payload.get("refine_steps_taken", 0))

    @property
    def refine_objective(self) -> list[float]:
        """The refinement's objective per step (empty without refinement)."""
        return list(self._payload.get("refine_objective", []))

    def graph_summary(self) -> str:
        """One line on the graph the model runs on: the mesh, or its working graph."""
        sizes = self.hierarchy.sizes
        if self.hierarchy.working is None:
            return f"model on the {sizes[0]}-node mesh itself"
        return f"model on a working graph of {sizes[0]} clusters of the {self.hierarchy.mesh_nodes}-node mesh"

    def sites(self, ids=(), xyz: np.ndarray | None = None, regions=(), tolerance: float = SITE_TOLERANCE) -> np.ndarray:
        """Node ids of sites given as node ids, points (K, 3) in mm and region names (:mod:`shared.sites`)."""
        parts = [np.asarray(ids, np.int64).reshape(-1)]
        if xyz is not None:
            parts.append(nearest_nodes(self.mesh.points, xyz, tolerance))
        if len(regions):
            parts.append(region_nodes(self.labels, self.mesh.points, regions))
        nodes = np.concatenate(parts)
        refuse_repeated(nodes, site_names(parts[0], xyz, regions))
        return nodes

    def predict(
        self, sites, samples: int = 0, seed: int = 0, on_estimate: Callable[[float, float], None] | None = None
    ) -> Prediction:
        """Full-mesh sequences for stimulation nodes ``sites``; ``samples > 1`` also draws ``c`` for a spread,
        accumulated draw by draw (memory of three predictions, whatever ``samples``). ``on_estimate(seconds,
        megabytes)`` hears what the draws will cost, timed on the mean prediction, before they start."""
        n = self.mesh.n_nodes
        sites = np.asarray(sites).reshape(-1)
        bad = [int(s) for s in sites if not 0 <= int(s) < n]
        if bad or not len(sites):
            raise InputError(f"stimulation nodes {bad or list(sites)} are not nodes of the {n}-node mesh")
        s = torch.as_tensor(sites.astype(np.int64), device=self.device)
        t0 = time.perf_counter()
        with torch.no_grad():
            u = self.model.generate(s, self.hierarchy, self.posterior.mu, evidence=self.evidence)
            seconds = time.perf_counter() - t0
            spread = act_spread = None
            if samples > 1:
                if on_estimate is not None:
                    on_estimate(samples * seconds, 3 * u.numel() * 8 / 2**20)
                g = torch.Generator().manual_seed(seed)
                draws = (
                    self.model.generate(s, self.hierarchy, self.posterior.sample(g), evidence=self.evidence)
                    .cpu()
                    .numpy()
                    for _ in range(samples)
                )
                spread, act_spread = _spreads(draws, self.times)
        ecg = None
        if self.lead_field is not None:
            ecg = self.lead_field.ecg(u.cpu()).numpy()
        u = u.cpu().numpy()
        activated = (u.max(axis=1) >= 0.5).mean(axis=1)
        return Prediction(sites.astype(np.int64), u, self.times, self.mesh, spread, seconds, activated, act_spread, ecg)

    def tissue(self, samples: int = TISSUE_SAMPLES, seed: int = 0) -> TissueEstimate:
        """What the heart infers about its tissue: abnormal-tissue probability per node and the healthy CV in m/s,
        each with its spread over ``samples`` draws of ``c`` (:mod:`learner.tissue_estimate`)."""
        return estimate_tissue(self.model, self.posterior, self.hierarchy, self.mesh, samples, seed)

    def save(self, path: str | Path) -> Path:
        """Write the heart to ``path`` (a personalised surrogate file that :meth:`load` reads)."""
        path = Path(path)
        payload = {
            **self._payload,
            "kind": "personalized",
            "frames": self.model.frames,
            "model": self.model.state_dict(),
            "c_mu": self.posterior.mu.cpu(),
            "c_logvar": self.posterior.logvar.cpu(),
            "points": torch.as_tensor(self.mesh.points),
            "cells": torch.as_tensor(self.mesh.cells),
            "times": torch.as_tensor(np.asarray(self.times, np.float64)),
            "hierarchy": {key: torch.as_tensor(value) for key, value in self.hierarchy.arrays().items()},
        }
        if self.labels is not None:
            payload["labels"] = {key: torch.as_tensor(value) for key, value in self.labels.arrays().items()}
        save_checkpoint(path, payload)
        return path

    @classmethod
    def load(cls, path: str | Path, device: str = "cpu") -> PersonalizedHeart:
        """The heart saved in ``path`` (on ``device``), its graph hierarchy as saved (rebuilt for files without)."""
        placed = resolve_device(device)
        p = load_checkpoint(path, kind="personalized")
        try:
            return cls._from_payload(p, path, placed)
        except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"{path} is not a personalised heart this learner reads: {first}") from None

    @classmethod
    def _from_payload(cls, p: dict, path: str | Path, placed: torch.device) -> PersonalizedHeart:
        """The heart of a checked personalised file's entries ``p``, placed on device ``placed``."""
        config = config_from_mapping(p["config"])
        model = build_model(config.model, p["frames"])
        model.load_state_dict(p["model"])
        model.to(placed).eval()
        mesh = Mesh(points=p["points"].numpy(), cells=p["cells"].numpy(), name=p["subject"] or "mesh")
        if "hierarchy" in p:
            hierarchy = MeshHierarchy.from_arrays({k: v.numpy() for k, v in p["hierarchy"].items()}, str(path))
        else:
            hierarchy = _hierarchy(mesh, config.model)
        labels = SiteLabels.from_arrays({k: v.numpy() for k, v in p["labels"].items()}) if "labels" in p else None
        evidence = None
        if "context_peaks" in p:  # missing from files that predate it; only capture_evidence models need it
            evidence = SiteEvidence(p["context_peaks"], p["context_sites"], p["observed"]).to(placed)
        posterior = Posterior(p["c_mu"].to(placed), p["c_logvar"].to(placed))
        arrays = (
            "model",
            "c_mu",
            "c_logvar",
            "points",
            "cells",
            "times",
            "hierarchy",
            "labels",
            "kind",
            "format",
            DIGESTS,
        )
        payload = {key: value for key, value in p.items() if key not in arrays}
        return cls(model, posterior, hierarchy.to(placed), mesh, p["times"].numpy(), payload, labels, evidence)


def _hierarchy(mesh: Mesh, model_config) -> MeshHierarchy:
    """The graph hierarchy the model runs on for ``mesh`` (its working graph for a model that has one)."""
    return hierarchy_for_mesh(mesh, model_config.levels, model_config.coarsest, None, model_config.working_nodes)


def _model_times(ckpt: dict, config, observations: Observations) -> np.ndarray:
    """The frame times (model time units) of a model: recorded with a shipped model, else its training
    store's; a model with neither takes recordings as they come (their frame count is checked)."""
    if ckpt.get("times") is not None:
        return np.asarray(ckpt["times"], np.float64)
    if Path(config.data.store).exists():
        return StoreView(config.data.store).times
    if observations.activation is not None:
        raise InputError(
            f"the model records no frame times and its training store {config.data.store} is not there: "
            "activation-time maps need them; give potentials (obs) at the model's frames"
        )
    return observations.times


def _template(ckpt: dict, config) -> ApTemplate:
    """The action-potential template of a model (:mod:`learner.activation_maps`): shipped with its weights,
    else computed from its training store's training subjects."""
    if ckpt.get("ap_template") is not None:
        return ApTemplate.from_dict(ckpt["ap_template"])
    if not Path(config.data.store).exists():
        raise InputError(
            f"the model records no action-potential template and its training store {config.data.store} is not "
            "there: activation-time maps cannot be read as potentials; give potentials (obs_mv or obs)"
        )
    return template_from_store(config.data.store, list(ckpt.get("splits", {}).get("train", [])))


def personalize(
    checkpoint: str | Path,
    observations: Observations,
    out: str | Path | None = None,
    device: str = "cpu",
    refine: Refinement = Refinement(),
) -> PersonalizedHeart:
    """Embed the context set on ``device`` into a :class:`PersonalizedHeart` (saved to ``out`` when given).

    Recordings that show no wave are left out (module docstring; a warning
    names them); none left is an :class:`InputError`. ``refine.steps > 0``
    refines ``c`` on the context set (:mod:`learner.refine`): the heart's ``c``
    mean is then the refined one, its log-variance the encoder's.
    """
    placed = resolve_device(device)
    model, config, ckpt = load_model(checkpoint, placed)
    if not isinstance(model, MetaPNS):
        raise InputError(f"{checkpoint} is a PNS model: it has no context embedding to personalise")
    observations = observations.at_frames(_model_times(ckpt, config, observations), lambda: _template(ckpt, config))
    if observations.ecg is not None:
        return _personalize_from_ecg(model, ckpt, config, observations, out, placed, refine)
    if observations.obs.shape[1] != model.frames:
        raise InputError(f"observations have {observations.obs.shape[1]} frames, the model expects {model.frames}")
    activated = recorded_fraction(observations.obs, observations.observed)
    wave = started_wave(activated)
    dropped = [
        (int(site), round(float(share), 4)) for site, share, w in zip(observations.sites, activated, wave) if not w
    ]
    if not wave.any():
        raise InputError(
            f"none of the {len(wave)} recordings shows a propagating wave (at most {100 * activated.max():.0f}% of "
            "the observed nodes activate): each site's stimulus excited its patch alone, so the recordings say "
            "nothing about how this heart conducts; record sites outside scar cores"
        )
    if dropped:
        warnings.warn(
            "left out recording(s) that show no propagating wave (node id, share of observed nodes activated): "
            + ", ".join(f"{site} ({100 * share:.1f}%)" for site, share in dropped),
            NoWaveWarning,
            stacklevel=2,
        )
    hier = _hierarchy(observations.mesh, config.model).to(placed)
    obs = torch.as_tensor(observations.obs[wave], dtype=torch.float32, device=placed)
    observed = torch.as_tensor(observations.observed, device=placed)
    recorded = None if observations.recorded is None else torch.as_tensor(observations.recorded[wave], device=placed)
    sites = torch.as_tensor(np.asarray(observations.sites, np.int64)[wave])
    t0 = time.perf_counter()
    with torch.no_grad():
        post = model.embed(obs, observed, hier, recorded)
    evidence = SiteEvidence.from_context(obs, observed, sites)  # its sites on obs's device
    objective, taken = [], 0
    if refine.steps:
        target, record = recorded_values(obs, observed, recorded), observed_nodes(observed)
        c, objective, taken = refine_context(model, post, target, record, evidence.sites, hier, evidence, refine)
        post = Posterior(c, post.logvar)
    payload = {
        "config": ckpt["config"],
        "subject": observations.subject,
        "context_sites": sites,
        "context_peaks": evidence.peaks.cpu(),
        "context_activated": torch.as_tensor(activated),
        "dropped": dropped,
        "refine_steps": refine.steps,
        "refine_steps_taken": taken,
        "refine_objective": objective,
        "embed_seconds": time.perf_counter() - t0,
        "observed": observed.cpu(),
    }
    heart = PersonalizedHeart(
        model,
        Posterior(post.mu.detach(), post.logvar),
        hier,
        observations.mesh,
        np.asarray(observations.times),
        payload,
        observations.labels,
        evidence.to(placed),
    )
    if out is not None:
        heart.save(out)
    return heart


def _personalize_from_ecg(
    model: MetaPNS,
    ckpt: dict,
    config: LearnerConfig,
    observations: Observations,
    out: str | Path | None,
    placed: torch.device,
    refine: Refinement,
) -> PersonalizedHeart:
    """:func:`personalize` from 12-lead ECGs: the model's ECG encoder embeds them; the heart keeps the mesh's
    lead field, so its predictions come with their ECGs. No recording is left out (an ECG does not show
    whether a wave started); ``refine`` fits ``c`` to the ECGs through the lead field
    (:func:`~learner.refine.ecg_leads`)."""
    if model.ecg_encoder is None:
        raise InputError(
            "this model reads no ECGs (it was trained without model.ecg_encoder); the shipped model `anatomies` does"
        )
    if observations.ecg.shape[2] != model.frames:
        raise InputError(f"the ECGs have {observations.ecg.shape[2]} frames, the model expects {model.frames}")
    hier = _hierarchy(observations.mesh, config.model).to(placed)
    lead_field = LeadField.of_mesh(observations.mesh, observations.electrodes).to(placed)
    sites = torch.as_tensor(np.asarray(observations.sites, np.int64))
    t0 = time.perf_counter()
    ecg = torch.as_tensor(observations.ecg, device=placed)
    with torch.no_grad():
        post = model.embed_ecg(ecg, lead_field, sites.to(placed), hier)
    objective, taken = [], 0
    if refine.steps:
        scale = float(ecg.abs().max())
        record = ecg_leads(lead_field, scale)
        c, objective, taken = refine_context(model, post, ecg / scale, record, sites.to(placed), hier, None, refine)
        post = Posterior(c, post.logvar)
    payload = {
        "config": ckpt["config"],
        "subject": observations.subject,
        "context_sites": sites,
        "recorded": "ecg",
        "lead_matrix": lead_field.matrix.cpu(),
        "lead_density": lead_field.density.cpu(),
        "dropped": [],
        "refine_steps": refine.steps,
        "refine_steps_taken": taken,
        "refine_objective": objective,
        "embed_seconds": time.perf_counter() - t0,
    }
    heart = PersonalizedHeart(
        model, post, hier, observations.mesh, np.asarray(observations.times), payload, observations.labels
    )
    if out is not None:
        heart.save(out)
    return heart


def predict(
    personalized: str | Path | PersonalizedHeart, sites, samples: int = 0, seed: int = 0, device: str = "cpu"
) -> Prediction:
    """:meth:`PersonalizedHeart.predict` of a heart, or of the heart saved in a file (read on ``device``)."""
    heart = (
        personalized if isinstance(personalized, PersonalizedHeart) else PersonalizedHeart.load(personalized, device)
    )
    return heart.predict(sites, samples, seed)


def _spreads(draws: Iterable[np.ndarray], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations over ``draws`` (each (S, T, N)), accumulated one draw at a time (Welford): of the
    potential (S, T, N), and of the activation time (S, N) over the draws that activate (NaN where none does)."""
    count = 0
    for draw in draws:
        act = np.stack([activation_times(u, times) for u in draw])
        if count == 0:
            mean, m2 = np.zeros_like(draw, np.float64), np.zeros_like(draw, np.float64)
            n_act, mean_act, m2_act = (np.zeros(act.shape) for _ in range(3))
        count += 1
        delta = draw - mean
        mean += delta / count
        m2 += delta * (draw - mean)
        hit = np.isfinite(act)
        n_act += hit
        delta_act = np.where(hit, act - mean_act, 0.0)
        mean_act += np.where(hit, delta_act / np.maximum(n_act, 1), 0.0)
        m2_act += np.where(hit, delta_act * (act - mean_act), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        act_spread = np.where(n_act > 0, np.sqrt(m2_act / n_act), np.nan)
    return np.sqrt(m2 / count).astype(np.float32), act_spread


def write_vtk(prediction: Prediction, folder: str | Path) -> list[Path]:
    """A ParaView time series per site (``site-<node>.pvd``, :func:`shared.vtk.write_time_series`): ``V_mV``
    and ``u`` per frame (and ``spread_mV`` with draws), ``activation_ms`` (and ``activation_spread_ms``)."""
    mesh, times_ms = prediction.mesh, np.asarray(prediction.times, np.float64) * MS_PER_TIME_UNIT
    paths = []
    for i, site in enumerate(prediction.sites):
        frames = {"V_mV": to_millivolts(prediction.u[i]), "u": prediction.u[i]}
        static = {"activation_ms": prediction.activation[i] * MS_PER_TIME_UNIT}
        if prediction.spread is not None:
            frames["spread_mV"] = 100.0 * prediction.spread[i]
            static["activation_spread_ms"] = prediction.activation_spread[i] * MS_PER_TIME_UNIT
        paths.append(write_time_series(folder, f"site-{int(site)}", mesh.points, mesh.cells, times_ms, frames, static))
    return paths


def plot_prediction(prediction: Prediction, path: str | Path) -> Path:
    """A PNG of the predicted activation-time maps (ms), one row per site marked with a star, front and back
    views on one colour scale; with draws, the spread of the activation time beside each map."""
    from learner.plot import plot_activation_panels

    rows = []
    for i, site in enumerate(prediction.sites):
        cols = [("predicted activation", prediction.activation[i] * MS_PER_TIME_UNIT)]
        if prediction.spread is not None:
            cols.append(("spread", prediction.activation_spread[i] * MS_PER_TIME_UNIT, "spread"))
        rows.append((f"site {int(site)}", cols))
    sites = list(prediction.mesh.points[prediction.sites])
    return plot_activation_panels(prediction.mesh.points, rows, path, sites=sites)
