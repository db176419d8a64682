"""A subject's recordings: what a personalisation reads, from a store or from an observation file.

An observation file (docs/formats.md) is an ``.npz`` of the arrays of
:data:`OBSERVATION_ARRAYS`; its sites are node ids (``sites``) or points in mm
(``site_xyz``, each the nearest node within :data:`~shared.sites.SITE_TOLERANCE`).
The mesh is the file's own (``points``, ``cells``) or a mesh file read as it is
(:func:`read_mesh_file`): any resolution, node ids as in the file. Region
labels travel with either (:class:`~shared.sites.SiteLabels`), for sites named
by region.
"""

from __future__ import annotations

import warnings
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from learner.activation_maps import ApTemplate
from learner.data.episodes import load_episode
from learner.ecg import resample_ecg
from learner.plausibility import (
    check_ecg,
    check_electrodes,
    check_frame_span,
    check_map_spread,
    check_map_window,
    check_millivolts,
    check_points_scale,
    unmapped_holes,
)
from learner.store_view import StoreView
from shared.ecg import LEADS, Electrodes
from shared.errors import InputError, StimulusError
from shared.mesh import Mesh, axis_from_point_data
from shared.sites import SITE_TOLERANCE, SiteLabels, nearest_nodes
from shared.units import MS_PER_TIME_UNIT, U_RANGE, from_millivolts

__all__ = [
    "OBSERVATION_ARRAYS",
    "Observations",
    "UnmappedWarning",
    "resample_frames",
    "read_npz",
    "observations_from_store",
    "observations_from_file",
    "read_mesh_file",
]


class UnmappedWarning(UserWarning):
    """Nodes of an activation-time map left out because not every recording maps them."""


@dataclass
class Observations:
    """A subject's context set: stimulation nodes, recordings and where they were recorded.

    The recordings are potential sequences ``obs`` (K, T, N) of the
    dimensionless ``u`` at frame ``times`` (model time units), or activation
    times ``activation`` (K, N) in model time units (``+inf``: mapped, never
    activated), which :meth:`at_frames` renders as potentials
    (:mod:`learner.activation_maps`), or 12-lead ECGs ``ecg`` (K, 12, T) in mV
    at ``times``, leads in the order of :data:`shared.ecg.LEADS`, recorded
    through ``electrodes`` (None: the standard placement by the heart's axes);
    ``observed`` then marks no node. ``labels``: the mesh's region labels
    where known (sites by region). ``recorded`` (K, T, N) bool, set by
    :meth:`at_frames` for activation maps: the values the recordings fix
    (:meth:`~learner.activation_maps.ApTemplate.fixed`); None: every frame of
    every observed node.
    """

    mesh: Mesh
    sites: np.ndarray  # (K,) stimulation node ids
    obs: np.ndarray | None  # (K, T, N) observed u (anything at unobserved nodes is ignored); None with activation
    observed: np.ndarray  # (N,) bool
    times: np.ndarray  # (T,) model time units
    subject: str = ""
    labels: SiteLabels | None = None
    activation: np.ndarray | None = None  # (K, N) model time units, +inf never activated; instead of obs
    ecg: np.ndarray | None = None  # (K, 12, T) mV at times; instead of obs
    electrodes: Electrodes | None = None  # where the ECG was recorded (None: the standard placement)
    recorded: np.ndarray | None = None  # (K, T, N) bool with obs: the values fixed (None: every frame observed)

    def __post_init__(self) -> None:
        given = [name for name in ("obs", "activation", "ecg") if getattr(self, name) is not None]
        if len(given) != 1:
            raise InputError(
                "give the recordings as potentials (obs), activation times or ECGs, one of them: got "
                + (", ".join(given) or "none")
            )
        k, n = len(self.sites), len(self.mesh.points)
        recorded = getattr(self, given[0])
        if len(recorded) < 1 or k < 1:
            raise InputError("context size must be >= 1: give at least one observed simulation")
        shape = {"obs": (k, len(self.times), n), "activation": (k, n), "ecg": (k, len(LEADS), len(self.times))}
        if recorded.shape != shape[given[0]] or self.observed.shape != (n,):
            raise InputError(
                f"observations do not fit together: {given[0]} {recorded.shape}, observed {self.observed.shape}, "
                f"sites {k}, times {len(self.times)}, mesh nodes {n}"
            )
        if self.ecg is None and not self.observed.any():
            raise InputError("no observed node: observed is false everywhere, so no sequence is observed anywhere")
        if self.ecg is not None:
            if not np.isfinite(self.ecg).all():
                raise InputError("the ECGs contain NaN or inf")
            check_ecg(self.ecg)
            if self.electrodes is not None:
                check_electrodes(self.electrodes.positions, self.electrodes.names, self.mesh)
        elif self.obs is not None:
            self._check_potentials()
            self.obs = np.where(self.observed, self.obs, 0.0).astype(np.float32)  # unobserved: NaN or anything
        elif np.isnan(self.activation[:, self.observed]).any() or (self.activation[:, self.observed] < 0).any():
            raise InputError("activation times must be >= 0 (or +inf: never activated) at every observed node")
        else:
            check_map_spread(self.activation * MS_PER_TIME_UNIT, self.observed)
        if self.recorded is not None and (self.obs is None or self.recorded.shape != self.obs.shape):
            raise InputError("recorded marks the values of potentials obs and must have their shape (K, T, N)")
        bad = [int(s) for s in self.sites if not 0 <= s < n]
        if bad:
            raise InputError(f"stimulation nodes {bad} are not nodes of the {n}-node mesh")
        repeated = sorted({int(s) for s in self.sites if list(self.sites).count(s) > 1})
        if repeated:
            raise InputError(f"stimulation node(s) {repeated} recorded more than once: give each site one recording")
        if self.labels is not None and self.labels.n_nodes != n:
            raise InputError(f"region labels cover {self.labels.n_nodes} nodes, the mesh has {n}")

    def _check_potentials(self) -> None:
        seen = self.obs[:, :, self.observed]
        if not np.isfinite(seen).all():
            raise InputError("observations contain NaN or inf at observed nodes")
        lo, hi = float(seen.min()), float(seen.max())
        if lo < U_RANGE[0] or hi > U_RANGE[1]:
            raise InputError(
                f"observations range from {lo:.4g} to {hi:.4g} at observed nodes, outside [{U_RANGE[0]:g}, "
                f"{U_RANGE[1]:g}]: the model's values are the dimensionless potential u (rest 0, peak about 1; "
                "V = 100 u - 80 mV), so give u as obs, or millivolts as obs_mv"
            )

    def at_frames(self, times: np.ndarray, template: Callable[[], ApTemplate]) -> Observations:
        """These recordings as potentials at the model's frame ``times`` (model time units).

        Activation times are rendered through ``template()`` (called only for
        them), with ``recorded`` marking the frames they fix; potentials at
        other frame times are resampled linearly (:func:`resample_frames`).
        """
        times = np.asarray(times, np.float64)
        if self.ecg is not None:
            ecg = resample_ecg(self.ecg, self.times * MS_PER_TIME_UNIT, times * MS_PER_TIME_UNIT)
            return replace(self, ecg=ecg, times=times)
        if self.activation is not None:
            check_map_window(self.activation, self.observed, times)
            waveform = template()
            recorded = waveform.fixed(self.activation, times) & self.observed
            return replace(
                self, obs=waveform.render(self.activation, times), times=times, activation=None, recorded=recorded
            )
        if len(self.times) == len(times) and np.allclose(self.times, times, rtol=1e-3, atol=1e-6):
            return self
        check_frame_span(self.times, times)
        return replace(self, obs=resample_frames(self.obs, self.times, times), times=times)


def _span_ms(times: np.ndarray) -> str:
    """``first, second, ..., last ms`` of a time axis in model time units."""
    t = [float(v) * MS_PER_TIME_UNIT for v in times]
    listed = ", ".join(f"{v:.2f}" for v in t) if len(t) <= 3 else f"{t[0]:.2f}, {t[1]:.2f}, ..., {t[-1]:.2f}"
    return f"{listed} ms"


def resample_frames(obs: np.ndarray, times: np.ndarray, to: np.ndarray) -> np.ndarray:
    """Sequences ``obs`` (K, T, N) at ``times`` (T,) resampled linearly to frame times ``to`` (T',).

    The recording must span ``to`` up to one of its own frame intervals at
    either end (there it holds its first or last value); anything shorter is
    refused with the frame times expected.
    """
    times = np.asarray(times, np.float64)
    if len(times) < 2 or np.any(np.diff(times) <= 0):
        raise InputError(f"frame times must increase strictly (at least 2 frames), got {_span_ms(times)}")
    step = float(np.max(np.diff(times)))
    if times[0] > to[0] + step or times[-1] < to[-1] - step:
        raise InputError(
            f"recordings at {_span_ms(times)} do not cover the model's {len(to)} frames at {_span_ms(to)} "
            f"({(to[1] - to[0]) * MS_PER_TIME_UNIT:.2f} ms apart, after the stimulus): record from at most "
            f"{(to[0] + step) * MS_PER_TIME_UNIT:.1f} ms to at least {(to[-1] - step) * MS_PER_TIME_UNIT:.1f} ms"
        )
    right = np.clip(np.searchsorted(times, to, side="right"), 1, len(times) - 1)
    left = right - 1
    w = np.clip((to - times[left]) / (times[right] - times[left]), 0.0, 1.0)[None, :, None]
    return ((1 - w) * obs[:, left, :] + w * obs[:, right, :]).astype(np.float32)


def observations_from_store(
    store: str | Path,
    subject: str,
    sites: list[int],
    observe: str,
    xyz: np.ndarray | None = None,
    tolerance: float = SITE_TOLERANCE,
) -> Observations:
    """Observe ``subject``'s simulations at stimulation nodes ``sites`` through node set ``observe``; points
    ``xyz`` (K, 3) in mm add the simulated site nearest each, within ``tolerance`` mm."""
    view = StoreView(store)
    view.check_subject(subject)
    mesh_id = view.mesh_of[subject]
    stored = view.sites(mesh_id)
    if xyz is not None:
        sites = [*sites, *nearest_nodes(view.mesh(mesh_id).points, xyz, tolerance, stored, "simulated site").tolist()]
    if not sites:
        raise InputError(f"give the context sites of subject {subject!r}: node ids or points")
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
    "sites": (1, "iu"),  # (K,) node ids, or
    "site_xyz": (2, "fiu"),  # (K, 3) points in mm
    "obs_mv": (3, "fiu"),  # (K, T, N) potentials in mV, or
    "obs": (3, "fiu"),  # (K, T, N) the dimensionless u, or
    "activation_ms": (2, "fiu"),  # (K, N) activation times in ms, NaN unmapped, +inf never activated
    "observed": (1, "biu"),  # (N,) 0/1
    "times_ms": (1, "fiu"),  # (T,) ms, or
    "times": (1, "fiu"),  # (T,) model time units
    "ecg_mv": (3, "fiu"),  # (K, 12, T) 12-lead ECGs in mV, or the same as
    "ecg": (3, "fiu"),
    "leads": (1, "U"),  # (12,) the ECG's lead names
    "ecg_times_ms": (1, "fiu"),  # (T,) ms
    "electrodes": (1, "U"),  # (E,) electrode names
    "electrode_xyz_mm": (2, "fiu"),  # (E, 3) electrode positions in mm
    "bipolar_mv": (1, "fiu"),  # (N,) bipolar voltage in mV with activation_ms: unmapped below SCAR_BIPOLAR_MV is scar
    "no_capture": (1, "biu"),  # (N,) 0/1 with activation_ms: nodes that never activate (their times NaN or inf)
}
#: Bipolar voltage (mV) below which mapping systems call tissue dense scar (0.5-1.5 mV: border zone).
SCAR_BIPOLAR_MV = 0.5
#: Groups of arrays of which a file gives exactly one (``sites`` and ``site_xyz`` may both be given if they agree).
ONE_OF = {
    "sites": ("sites", "site_xyz"),
    "recordings": ("obs_mv", "obs", "activation_ms", "ecg_mv", "ecg"),
    "frame times": ("times_ms", "times"),
}
_KINDS = {"f": "float", "i": "integer", "u": "integer", "b": "bool", "U": "string"}
_UNREADABLE = (ValueError, EOFError, zipfile.BadZipFile, zlib.error)  # what np.load raises for bad bytes


def read_npz(path: Path, names: list[str], what: str) -> dict[str, np.ndarray]:
    """The arrays ``names`` that the ``.npz`` archive ``path`` holds (the others left out), each read whole; a
    file that is no archive, or an array whose bytes do not decode, is refused with one line."""
    try:
        data = np.load(path)
    except _UNREADABLE as exc:
        raise InputError(f"{path} is not an .npz archive of arrays: {exc}") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"{path} holds a single array, not an .npz archive of {what}")
    arrays = {}
    with data:
        for name in names:
            if name not in data.files:
                continue
            try:
                arrays[name] = data[name]
            except _UNREADABLE as exc:
                raise InputError(f"{path}: array {name!r} cannot be read: {exc}") from None
    return arrays


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """The arrays of :data:`OBSERVATION_ARRAYS` (and region labels) that ``path`` holds, each checked for its
    number of dimensions and dtype kind."""
    arrays = read_npz(path, [*OBSERVATION_ARRAYS, *SiteLabels.NAMES], str(list(OBSERVATION_ARRAYS)))
    for name, array in arrays.items():
        ndim, kinds = OBSERVATION_ARRAYS.get(name, (1, "biu"))
        if array.ndim != ndim or array.dtype.kind not in kinds:
            allowed = " or ".join(dict.fromkeys(_KINDS[k] for k in kinds))
            raise InputError(
                f"{path}: {name} must be a {ndim}-D array of {allowed} values, got {array.ndim}-D {array.dtype}"
            )
    return arrays


def _check_present(path: Path, a: dict[str, np.ndarray], mesh_given: bool) -> None:
    """Refuse a file lacking an array it needs, or giving two of a :data:`ONE_OF` group."""
    for group, names in ONE_OF.items():
        given = [name for name in names if name in a]
        if len(given) > 1 and group != "sites":
            raise InputError(f"{path}: give one of {' and '.join(given)} ({group}), not both")
    needed = ["sites", "recordings"]
    if "ecg_mv" in a or "ecg" in a:
        needed += ["ecg_times_ms"]
    elif "activation_ms" not in a:
        needed += ["frame times", "observed"]
    if not mesh_given:
        needed += ["points", "cells"]
    missing = [" or ".join(ONE_OF.get(need, (need,))) for need in needed if not set(ONE_OF.get(need, (need,))) & set(a)]
    if missing:
        raise InputError(f"{path} lacks array(s) {missing}")


def _recordings(path: Path, a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The recordings of a checked file as :class:`Observations` fields: ``obs`` (u) and ``times`` (model time
    units), or ``activation`` (model time units) with the nodes every recording maps as ``observed``, or ``ecg``
    (mV, leads in :data:`~shared.ecg.LEADS` order) with its ``times`` and ``electrodes``."""
    if "ecg_mv" in a or "ecg" in a:
        return _ecg_recordings(path, a)
    if "activation_ms" in a:
        act = _never_activated(path, a, a["activation_ms"].astype(np.float64))
        if (act < 0).any():
            raise InputError(
                f"{path}: activation_ms has {int((act < 0).sum())} negative time(s), down to {np.nanmin(act):.4g} ms: "
                "give ms after the stimulus starts (NaN: unmapped, inf: mapped and never activated)"
            )
        mapped = ~np.isnan(act)
        observed = mapped.all(axis=0) if "observed" not in a else a["observed"].astype(bool)
        if "observed" in a and not mapped[:, observed].all():
            raise InputError(f"{path}: activation_ms is NaN at nodes that observed marks as recorded")
        partial = int((mapped.any(axis=0) & ~observed).sum())
        if partial and "observed" not in a:
            warnings.warn(
                f"{partial} node(s) mapped in some recordings but not all are left out: the model reads the "
                f"{int(observed.sum())} nodes every recording maps",
                UnmappedWarning,
                stacklevel=3,
            )
        return {"obs": None, "activation": act / MS_PER_TIME_UNIT, "observed": observed, "times": np.zeros(0)}
    times = a["times"].astype(np.float64) if "times" in a else a["times_ms"] / MS_PER_TIME_UNIT
    if not np.isfinite(times).all():
        raise InputError(f"{path}: {'times' if 'times' in a else 'times_ms'} contains NaN or inf")
    observed = a["observed"].astype(bool)
    if "obs" in a:
        return {"obs": a["obs"].astype(np.float32), "observed": observed, "times": times}
    check_millivolts(a["obs_mv"][:, :, observed].astype(np.float64), f"{path}: obs_mv", ", or u as obs")
    return {"obs": from_millivolts(a["obs_mv"]).astype(np.float32), "observed": observed, "times": times}


def _never_activated(path: Path, a: dict[str, np.ndarray], act: np.ndarray) -> np.ndarray:
    """Activation maps (K, N) in ms with the nodes ``no_capture`` marks, and the unmapped (NaN) nodes whose
    ``bipolar_mv`` is below :data:`SCAR_BIPOLAR_MV`, made never activated (+inf)."""
    n = act.shape[1]
    for name in ("no_capture", "bipolar_mv"):
        if name in a and a[name].shape != (n,):
            raise InputError(f"{path}: {name} must hold one value per node ({n}), got shape {a[name].shape}")
    if "no_capture" in a:
        mask = a["no_capture"].astype(bool)
        timed = int(np.isfinite(act[:, mask]).any(axis=0).sum())
        if timed:
            raise InputError(f"{path}: no_capture marks {timed} node(s) that have an activation time in activation_ms")
        act = np.where(mask, np.inf, act)
    if "bipolar_mv" in a:
        volts = a["bipolar_mv"].astype(np.float64)
        if not np.isfinite(volts).all() or (volts < 0).any():
            raise InputError(f"{path}: bipolar_mv must be finite voltages >= 0 mV (peak-to-peak amplitude)")
        act = np.where(np.isnan(act) & (volts < SCAR_BIPOLAR_MV), np.inf, act)
    return act


def _warn_holes(path: Path, mesh: Mesh, activation_ms: np.ndarray, observed: np.ndarray) -> None:
    """Warn when the map leaves out (NaN) surface patches that mapped nodes enclose: a scar read as unmapped."""
    nodes, regions = unmapped_holes(mesh, np.isnan(activation_ms).all(axis=0), observed)
    if nodes:
        warnings.warn(
            f"{path}: {nodes} node(s) in {regions} region(s) enclosed by mapped nodes have no activation time (NaN: "
            "not mapped), so the model does not read them; if they never activate (scar), mark them +inf in "
            f"activation_ms, or give bipolar_mv (below {SCAR_BIPOLAR_MV:g} mV: scar) or no_capture",
            UnmappedWarning,
            stacklevel=3,
        )


def _ecg_recordings(path: Path, a: dict[str, np.ndarray]) -> dict:
    """The ECG fields of :class:`Observations` from a checked file (:func:`_recordings`)."""
    name = "ecg_mv" if "ecg_mv" in a else "ecg"
    times_ms = a["ecg_times_ms"].astype(np.float64)
    try:
        ecg = resample_ecg(a[name], times_ms, times_ms, a["leads"].tolist() if "leads" in a else None)
        electrodes = None
        if "electrodes" in a or "electrode_xyz_mm" in a:
            if not {"electrodes", "electrode_xyz_mm"} <= set(a):
                raise InputError("give the electrodes' names (electrodes) with their positions (electrode_xyz_mm)")
            electrodes = Electrodes(tuple(a["electrodes"].tolist()), a["electrode_xyz_mm"])
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    n = len(a["points"]) if "points" in a else None
    return {
        "obs": None,
        "ecg": ecg,
        "times": times_ms / MS_PER_TIME_UNIT,
        "electrodes": electrodes,
        "observed": None if n is None else np.zeros(n, bool),
    }


def read_mesh_file(path: str | Path) -> tuple[Mesh, SiteLabels | None]:
    """A mesh file (any meshio format) as it is: its points and its tetrahedra (or, without any, its
    triangles), with its long axis and region labels when its point data carry them (``simgen mesh`` writes
    both; the axis places the standard ECG electrodes).

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
            points = np.asarray(data.points, np.float64)[:, :3]
            try:
                axis = axis_from_point_data(data.point_data, len(points), str(path))
                labels = SiteLabels.from_arrays(data.point_data)
            except StimulusError as exc:
                raise InputError(f"{path}: {exc}") from None
            mesh = Mesh(points=points, cells=np.concatenate(blocks), name=path.stem, axis=axis)
            return mesh, labels
    raise InputError(f"{path} has no tetrahedra and no triangles (cell types: {[b.type for b in data.cells]})")


def observations_from_file(
    path: str | Path,
    mesh: Mesh | None = None,
    labels: SiteLabels | None = None,
    tolerance: float = SITE_TOLERANCE,
) -> Observations:
    """Observations from an ``.npz`` with the arrays of :data:`OBSERVATION_ARRAYS`, checked.

    With ``mesh`` (:func:`read_mesh_file`, and its ``labels``), the file may
    leave out ``points`` and ``cells``; where it has them, its points must be
    the mesh's nodes. Sites given as ``site_xyz`` are the nearest nodes within
    ``tolerance`` mm.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"observation file not found: {path}")
    a = _read_arrays(path)
    _check_present(path, a, mesh is not None)
    for name in ("points", "site_xyz"):
        if name in a and not np.isfinite(a[name]).all():
            raise InputError(f"{path}: {name} contains NaN or inf")
    if "observed" in a and not np.isin(a["observed"], (0, 1)).all():
        raise InputError(f"{path}: observed must hold 0/1 (or false/true) per node")
    if mesh is None:
        check_points_scale(a["points"], f"{path}: points")
        mesh = Mesh(points=a["points"], cells=a["cells"], name=path.stem)
    elif "points" in a and (a["points"].shape != mesh.points.shape or not np.allclose(a["points"], mesh.points)):
        raise InputError(
            f"{path}: its points are not the nodes of mesh {mesh.name!r} ({len(mesh.points)} nodes): the recordings "
            "must refer to the nodes of the mesh given with them (a mesh file is read as it is; `simgen simulate "
            "--nodes N` resamples, and its observation file then carries the resampled mesh)"
        )
    try:
        labels = labels or SiteLabels.from_arrays(a)
        sites = a["sites"] if "sites" in a else nearest_nodes(mesh.points, a["site_xyz"], tolerance)
    except StimulusError as exc:
        raise InputError(f"{path}: {exc}") from None
    if "sites" in a and "site_xyz" in a and not np.array_equal(sites, nearest_nodes(mesh.points, a["site_xyz"], 1e9)):
        raise InputError(f"{path}: sites and site_xyz name different nodes; give one of them")
    recordings = _recordings(path, a)
    if recordings["observed"] is None:  # an ECG marks no node
        recordings["observed"] = np.zeros(mesh.n_nodes, bool)
    if recordings.get("activation") is not None:
        _warn_holes(path, mesh, recordings["activation"], recordings["observed"])
    return Observations(mesh, sites, subject=path.stem, labels=labels, **recordings)
