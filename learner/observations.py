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

import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from learner.data.episodes import load_episode
from learner.store_view import StoreView
from shared.errors import InputError, StimulusError
from shared.mesh import Mesh
from shared.sites import SITE_TOLERANCE, SiteLabels, nearest_nodes
from shared.units import U_RANGE

__all__ = [
    "OBSERVATION_ARRAYS",
    "Observations",
    "observations_from_store",
    "observations_from_file",
    "read_mesh_file",
]


@dataclass
class Observations:
    """A subject's context set: stimulation nodes, observed sequences and where they were observed.

    ``labels``: the mesh's region labels where known (sites by region).
    """

    mesh: Mesh
    sites: np.ndarray  # (K,) stimulation node ids
    obs: np.ndarray  # (K, T, N) observed values (anything at unobserved nodes is ignored)
    observed: np.ndarray  # (N,) bool
    times: np.ndarray  # (T,) model time units
    subject: str = ""
    labels: SiteLabels | None = None

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
        repeated = sorted({int(s) for s in self.sites if list(self.sites).count(s) > 1})
        if repeated:
            raise InputError(f"stimulation node(s) {repeated} recorded more than once: give each site one recording")
        if self.labels is not None and self.labels.n_nodes != n:
            raise InputError(f"region labels cover {self.labels.n_nodes} nodes, the mesh has {n}")


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
    "obs": (3, "fiu"),  # (K, T, N)
    "observed": (1, "biu"),  # (N,) 0/1
    "times": (1, "fiu"),  # (T,)
}
#: Arrays a file may leave out: the sites are ``sites`` or ``site_xyz``; the mesh may come from a mesh file.
_EITHER_SITES = ("sites", "site_xyz")
_KINDS = {"f": "float", "i": "integer", "u": "integer", "b": "bool"}
_UNREADABLE = (ValueError, EOFError, zipfile.BadZipFile, zlib.error)  # what np.load raises for bad bytes


def _read_arrays(path: Path, optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays of :data:`OBSERVATION_ARRAYS` (and region labels) from ``path``, each checked; ``optional``
    ones may be absent, and one of ``sites`` and ``site_xyz`` must be there."""
    try:
        data = np.load(path)
    except _UNREADABLE as exc:
        raise InputError(f"{path} is not an .npz archive of arrays: {exc}") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise InputError(f"{path} holds a single array, not an .npz archive of {list(OBSERVATION_ARRAYS)}")
    arrays = {}
    with data:
        absent = set(optional) | set(_EITHER_SITES)
        missing = [name for name in OBSERVATION_ARRAYS if name not in data.files and name not in absent]
        if not set(_EITHER_SITES) & set(data.files):
            missing.append("sites (or site_xyz)")
        if missing:
            raise InputError(f"{path} lacks array(s) {missing}")
        for name in [*OBSERVATION_ARRAYS, *SiteLabels.NAMES]:
            if name not in data.files:
                continue
            try:
                array = data[name]
            except _UNREADABLE as exc:
                raise InputError(f"{path}: array {name!r} cannot be read: {exc}") from None
            ndim, kinds = OBSERVATION_ARRAYS.get(name, (1, "biu"))
            if array.ndim != ndim or array.dtype.kind not in kinds:
                allowed = " or ".join(dict.fromkeys(_KINDS[k] for k in kinds))
                raise InputError(
                    f"{path}: {name} must be a {ndim}-D array of {allowed} values, got {array.ndim}-D {array.dtype}"
                )
            arrays[name] = array
    return arrays


def read_mesh_file(path: str | Path) -> tuple[Mesh, SiteLabels | None]:
    """A mesh file (any meshio format) as it is: its points and its tetrahedra (or, without any, its
    triangles), and its region labels when its point data carry them (``simgen mesh`` writes them).

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
            mesh = Mesh(points=points, cells=np.concatenate(blocks), name=path.stem)
            return mesh, SiteLabels.from_arrays(data.point_data)
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
    a = _read_arrays(path, optional=("points", "cells") if mesh is not None else ())
    for name in ("points", "times", "site_xyz"):
        if name in a and not np.isfinite(a[name]).all():
            raise InputError(f"{path}: {name} contains NaN or inf")
    if not np.isin(a["observed"], (0, 1)).all():
        raise InputError(f"{path}: observed must hold 0/1 (or false/true) per node")
    if mesh is None:
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
    return Observations(
        mesh, sites, a["obs"].astype(np.float32), a["observed"].astype(bool), a["times"], path.stem, labels
    )
