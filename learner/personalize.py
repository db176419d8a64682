"""Personalise and predict: a subject's few observations -> a saved surrogate -> new stimulation sites.

A personalised surrogate file holds the trained weights, the context embedding
``c`` (mean and log-variance of p(c | Y)), the mesh and the frame times, so
:func:`predict` needs neither the store nor the training run.
"""

from __future__ import annotations

import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from learner.config import config_from_mapping
from learner.data.episodes import load_episode
from learner.graph.hierarchy import hierarchy_for_mesh
from learner.models.site_evidence import SiteEvidence
from learner.models.surrogate import MetaPNS, Posterior, build_model
from learner.refine import Refinement, refine_context
from learner.runtime import resolve_device
from learner.store_view import StoreView
from learner.train.checkpoint import load_checkpoint, save_checkpoint
from learner.train.trainer import load_model
from shared.errors import InputError
from shared.mesh import Mesh
from shared.units import MS_PER_TIME_UNIT, U_RANGE

__all__ = [
    "Observations",
    "Prediction",
    "observations_from_store",
    "observations_from_file",
    "mesh_from_file",
    "personalize",
    "predict",
    "write_vtk",
    "plot_prediction",
]


@dataclass
class Observations:
    """A subject's context set: stimulation nodes, observed sequences and where they were observed."""

    mesh: Mesh
    sites: np.ndarray  # (K,) stimulation node ids
    obs: np.ndarray  # (K, T, N) observed values (anything at unobserved nodes is ignored)
    observed: np.ndarray  # (N,) bool
    times: np.ndarray  # (T,) model time units
    subject: str = ""

    def __post_init__(self) -> None:
        k, t, n = self.obs.shape
        if k < 1:
            raise InputError("context size must be >= 1: give at least one observed simulation")
        if n != len(self.mesh.points) or self.observed.shape != (n,) or len(self.sites) != k or len(self.times) != t:
            raise InputError(
                f"observations do not fit together: obs {self.obs.shape}, observed {self.observed.shape}, "
                f"sites {len(self.sites)}, times {len(self.times)}, mesh nodes {len(self.mesh.points)}"
            )
        if not self.observed.any():
            raise InputError("no observed node: observed is false everywhere, so no sequence is observed anywhere")
        seen = self.obs[:, :, self.observed]
        if not np.isfinite(seen).all():
            raise InputError("observations contain NaN or inf at observed nodes")
        lo, hi = float(seen.min()), float(seen.max())
        if lo < U_RANGE[0] or hi > U_RANGE[1]:
            raise InputError(
                f"observations range from {lo:.4g} to {hi:.4g} at observed nodes, outside [{U_RANGE[0]:g}, "
                f"{U_RANGE[1]:g}]: the model's values are the dimensionless potential u (rest 0, peak about 1; "
                "V = 100 u - 80 mV), so give u, not millivolts or scaled values"
            )
        bad = [int(s) for s in self.sites if not 0 <= s < n]
        if bad:
            raise InputError(f"stimulation nodes {bad} are not nodes of the {n}-node mesh")


def observations_from_store(store: str | Path, subject: str, sites: list[int], observe: str) -> Observations:
    """Observe ``subject``'s simulations at stimulation nodes ``sites`` through node set ``observe``."""
    view = StoreView(store)
    view.check_subject(subject)
    mesh_id = view.mesh_of[subject]
    stored = view.sites(mesh_id)
    unknown = sorted(set(int(s) for s in sites) - set(stored.tolist()))
    if unknown:
        raise InputError(f"subject {subject!r} has no simulation stimulated at node(s) {unknown}")
    rows = [int(np.flatnonzero(stored == s)[0]) for s in sites]
    ep = load_episode(store, subject, rows, [], observe)
    return Observations(
        view.mesh(mesh_id), np.asarray(sites), ep.context_obs.numpy(), ep.observed.numpy(), ep.times.numpy(), subject
    )


#: Arrays of an observation file: dimensions and admissible dtype kinds (f float, i/u integer, b bool).
OBSERVATION_ARRAYS = {
    "points": (2, "fiu"),  # (N, 3) mm
    "cells": (2, "iu"),  # (M, 4) tetrahedra or (M, 3) triangles
    "sites": (1, "iu"),  # (K,)
    "obs": (3, "fiu"),  # (K, T, N)
    "observed": (1, "biu"),  # (N,) 0/1
    "times": (1, "fiu"),  # (T,)
}
_KINDS = {"f": "float", "i": "integer", "u": "integer", "b": "bool"}
_UNREADABLE = (ValueError, EOFError, zipfile.BadZipFile, zlib.error)  # what np.load raises for bad bytes


def _read_observation_arrays(path: Path, optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays of :data:`OBSERVATION_ARRAYS` from ``path`` (``optional`` ones may be absent), each checked."""
    try:
        data = np.load(path)
    except _UNREADABLE as exc:
        raise InputError(f"{path} is not an .npz archive of arrays: {exc}") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"{path} holds a single array, not an .npz archive of {list(OBSERVATION_ARRAYS)}")
    arrays = {}
    with data:
        missing = [name for name in OBSERVATION_ARRAYS if name not in data.files and name not in optional]
        if missing:
            raise InputError(f"{path} lacks array(s) {missing}")
        for name, (ndim, kinds) in OBSERVATION_ARRAYS.items():
            if name not in data.files:
                continue
            try:
                array = data[name]
            except _UNREADABLE as exc:
                raise InputError(f"{path}: array {name!r} cannot be read: {exc}") from None
            if array.ndim != ndim or array.dtype.kind not in kinds:
                allowed = " or ".join(dict.fromkeys(_KINDS[k] for k in kinds))
                raise InputError(
                    f"{path}: {name} must be a {ndim}-D array of {allowed} values, got {array.ndim}-D {array.dtype}"
                )
            arrays[name] = array
    return arrays


def mesh_from_file(path: str | Path) -> Mesh:
    """A mesh file (any meshio format) as it is: its points and its tetrahedra (or, without any, its triangles).

    Nothing is resampled or renumbered, so node ids are those of the file.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise InputError(f"mesh file not found: {path}")
    try:
        data = meshio.read(path)
    except Exception as exc:  # meshio raises many types for unreadable or unknown files
        first = str(exc).splitlines()[0] if str(exc) else repr(exc)
        raise InputError(f"{path} is not a readable mesh file: {first}") from None
    for cell_type in ("tetra", "triangle"):
        blocks = [block.data for block in data.cells if block.type == cell_type]
        if blocks:
            return Mesh(points=np.asarray(data.points, np.float64)[:, :3], cells=np.concatenate(blocks), name=path.stem)
    raise InputError(f"{path} has no tetrahedra and no triangles (cell types: {[b.type for b in data.cells]})")


def observations_from_file(path: str | Path, mesh: Mesh | None = None) -> Observations:
    """Observations from an ``.npz`` with the arrays of :data:`OBSERVATION_ARRAYS`, checked.

    With ``mesh`` (:func:`mesh_from_file`), the file may leave out ``points``
    and ``cells``; where it has them they must be the mesh's.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"observation file not found: {path}")
    a = _read_observation_arrays(path, optional=("points", "cells") if mesh is not None else ())
    for name in ("points", "times"):
        if name in a and not np.isfinite(a[name]).all():
            raise InputError(f"{path}: {name} contains NaN or inf")
    if not np.isin(a["observed"], (0, 1)).all():
        raise InputError(f"{path}: observed must hold 0/1 (or false/true) per node")
    if mesh is None:
        mesh = Mesh(points=a["points"], cells=a["cells"], name=path.stem)
    elif "points" in a and (a["points"].shape != mesh.points.shape or not np.allclose(a["points"], mesh.points)):
        raise InputError(f"{path}: its points are not the nodes of mesh {mesh.name!r} ({len(mesh.points)} nodes)")
    elif "cells" in a and not np.array_equal(a["cells"], mesh.cells):
        raise InputError(f"{path}: its cells are not those of mesh {mesh.name!r}")
    return Observations(
        mesh, a["sites"], a["obs"].astype(np.float32), a["observed"].astype(bool), a["times"], path.stem
    )


def _span(times) -> str:
    """``first, second, ..., last`` of a time axis."""
    t = [float(v) for v in times]
    return ", ".join(f"{v:g}" for v in t) if len(t) <= 3 else f"{t[0]:g}, {t[1]:g}, ..., {t[-1]:g}"


def personalize(
    checkpoint: str | Path,
    observations: Observations,
    out: str | Path,
    device: str = "cpu",
    refine: Refinement = Refinement(),
) -> dict:
    """Embed the context set (on ``device``) and save a personalised surrogate; returns timing and shape facts.

    ``refine.steps > 0`` refines ``c`` on the context set (:mod:`learner.refine`):
    the file's ``c_mu`` is then the refined ``c``, its ``c_logvar`` the encoder's,
    and the result's ``refine_objective`` the objective per step (empty without).
    """
    placed = resolve_device(device)
    model, config, ckpt = load_model(checkpoint, placed)
    if not isinstance(model, MetaPNS):
        raise InputError(f"{checkpoint} is a PNS model: it has no context embedding to personalise")
    if observations.obs.shape[1] != model.frames:
        raise InputError(f"observations have {observations.obs.shape[1]} frames, the model expects {model.frames}")
    expected = ckpt.get("times")  # a shipped model records its frame times
    if expected is not None and not np.allclose(observations.times, expected, rtol=1e-3, atol=1e-6):
        step = expected[1] - expected[0] if len(expected) > 1 else expected[0]
        raise InputError(
            f"observations are at times {_span(observations.times)}; the model expects {len(expected)} frames "
            f"at {_span(expected)} ({step:g} time units = {step * MS_PER_TIME_UNIT:.2f} ms apart, after the stimulus)"
        )
    hier = hierarchy_for_mesh(observations.mesh, config.model.levels, config.model.coarsest, None).to(placed)
    obs = torch.as_tensor(observations.obs, dtype=torch.float32, device=placed)
    observed = torch.as_tensor(observations.observed, device=placed)
    sites = torch.as_tensor(np.asarray(observations.sites, np.int64))
    t0 = time.perf_counter()
    with torch.no_grad():
        post = model.embed(obs, observed, hier)
    evidence = SiteEvidence.from_context(obs, observed, sites)  # its sites on obs's device
    objective = []
    if refine.steps:
        c, objective = refine_context(model, post, obs, observed, evidence.sites, hier, evidence, refine)
        post = Posterior(c, post.logvar)
    post = Posterior(post.mu.cpu(), post.logvar.cpu())
    seconds = time.perf_counter() - t0
    save_checkpoint(
        out,
        {
            "kind": "personalized",
            "config": ckpt["config"],
            "frames": model.frames,
            "model": ckpt["model"],
            "c_mu": post.mu,
            "c_logvar": post.logvar,
            "subject": observations.subject,
            "context_sites": sites,
            "context_peaks": evidence.peaks.cpu(),
            "refine_steps": refine.steps,
            "observed": observed.cpu(),
            "points": torch.as_tensor(observations.mesh.points),
            "cells": torch.as_tensor(observations.mesh.cells),
            "times": torch.as_tensor(np.asarray(observations.times, np.float64)),
        },
    )
    return {
        "embed_seconds": seconds,
        "context_size": len(observations.sites),
        "out": str(out),
        "refine_objective": objective,
    }


@dataclass
class Prediction:
    """Predicted sequences of a personalised surrogate."""

    sites: np.ndarray  # (S,)
    u: np.ndarray  # (S, T, N) mean prediction
    times: np.ndarray  # (T,)
    mesh: Mesh
    spread: np.ndarray | None = None  # (S, T, N) std over samples of c, when samples > 1
    seconds: float = 0.0


def predict(
    personalized: str | Path, sites: list[int], samples: int = 0, seed: int = 0, device: str = "cpu"
) -> Prediction:
    """Full-mesh sequences for new stimulation nodes (on ``device``); ``samples > 1`` also draws c for a spread."""
    placed = resolve_device(device)
    p = load_checkpoint(personalized, kind="personalized")
    config = config_from_mapping(p["config"])
    model = build_model(config.model, p["frames"])
    model.load_state_dict(p["model"])
    model.to(placed).eval()
    mesh = Mesh(points=p["points"].numpy(), cells=p["cells"].numpy(), name=p["subject"] or "mesh")
    n = len(mesh.points)
    bad = [int(s) for s in sites if not 0 <= int(s) < n]
    if bad or not sites:
        raise InputError(f"stimulation nodes {bad or sites} are not nodes of the {n}-node mesh")
    hier = hierarchy_for_mesh(mesh, config.model.levels, config.model.coarsest, None).to(placed)
    s = torch.as_tensor(np.asarray(sites, np.int64), device=placed)
    post = Posterior(p["c_mu"].to(placed), p["c_logvar"].to(placed))
    evidence = None
    if "context_peaks" in p:  # missing from files that predate it; only capture_evidence models need it
        evidence = SiteEvidence(p["context_peaks"], p["context_sites"], p["observed"]).to(placed)
    t0 = time.perf_counter()
    with torch.no_grad():
        u = model.generate(s, hier, post.mu, evidence=evidence)
        seconds = time.perf_counter() - t0
        spread = None
        if samples > 1:
            g = torch.Generator().manual_seed(seed)
            draws = torch.stack([model.generate(s, hier, post.sample(g), evidence=evidence) for _ in range(samples)])
            spread = draws.std(dim=0).cpu().numpy()
    return Prediction(np.asarray(sites), u.cpu().numpy(), p["times"].numpy(), mesh, spread, seconds)


def write_vtk(prediction: Prediction, folder: str | Path, threshold: float = 0.5) -> list[Path]:
    """One ``.vtu`` per site with ``u`` per frame and the predicted activation time (ms) as point data."""
    import meshio

    from learner.metrics import activation_times

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cell_type = "tetra" if prediction.mesh.cells.shape[1] == 4 else "triangle"
    paths = []
    for site, u in zip(prediction.sites, prediction.u):
        data = {f"u_{t:03d}": u[t] for t in range(u.shape[0])}
        data["activation_ms"] = activation_times(u, prediction.times, threshold) * MS_PER_TIME_UNIT
        path = folder / f"site-{int(site)}.vtu"
        meshio.write(path, meshio.Mesh(prediction.mesh.points, [(cell_type, prediction.mesh.cells)], point_data=data))
        paths.append(path)
    return paths


def plot_prediction(prediction: Prediction, path: str | Path, threshold: float = 0.5) -> Path:
    """A PNG of the predicted activation-time maps (ms), one row per site, front and back views."""
    from learner.metrics import activation_times
    from learner.plot import plot_activation_panels

    rows = [
        (
            f"site {int(site)}",
            [("predicted activation", activation_times(u, prediction.times, threshold) * MS_PER_TIME_UNIT)],
        )
        for site, u in zip(prediction.sites, prediction.u)
    ]
    return plot_activation_panels(prediction.mesh.points, rows, path)
