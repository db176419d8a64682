"""Export one simulation of a store as a ParaView time series (meshio ``.vtu`` + ``.pvd``).

One ``.vtu`` file per output frame carries the potential (``V_mV`` and ``u``)
and the static fields of the subject (``activation_ms``, ``a``, ``label``); a
``.pvd`` collection lists the frames with their times in ms
(:func:`shared.vtk.write_time_series`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import zarr

from shared.errors import InputError
from shared.integrity import SubjectReader, read_checked
from shared.reader import checked_subject_ids
from shared.schema import subject_path
from shared.vtk import write_time_series
from simgen.solver.cells.aliev_panfilov import MS_PER_TIME_UNIT, to_millivolts
from simgen.store.layout import check_store, read_mesh
from simgen.store.location import store_location

__all__ = ["export_vtk"]


def _subject_group(store: str, subject_id: str, attrs: dict) -> zarr.Group:
    """The subject's group; :class:`InputError` listing the known ids otherwise (a missing implied one: damage)."""
    known = checked_subject_ids(store, attrs)
    if subject_id not in known:
        raise InputError(f"unknown subject {subject_id!r} in {store}; subjects: {known}")
    return zarr.open_group(store, path=subject_path(subject_id), mode="r")


def _check_site(g: zarr.Group, subject_id: str, site_index: int) -> None:
    """:class:`InputError` unless ``site_index`` is a site of the subject (its chunk is checked as it is read)."""
    n_sites = g["u"].shape[0]
    if isinstance(site_index, bool) or not isinstance(site_index, (int, np.integer)):
        raise InputError(f"site index must be an integer, got {site_index!r}")
    if not 0 <= site_index < n_sites:
        raise InputError(f"site index {site_index} out of range for subject {subject_id!r}: use 0..{n_sites - 1}")


def export_vtk(store: str | Path, subject_id: str, site_index: int, out_dir: str | Path) -> Path:
    """Write the simulation of site ``site_index`` of ``subject_id`` as a ParaView time series.

    Parameters
    ----------
    store : folder or fsspec URL (``s3://bucket/name.zarr``) of the dataset store.
    subject_id : subject to export (e.g. ``"lv-healthy"``).
    site_index : index of the stimulation site (0-based, along the store's ``site`` axis).
    out_dir : folder for the files (created if needed).

    Returns
    -------
    Path
        The ``.pvd`` file; the frames are ``<subject>_site<i>_<frame>.vtu`` beside it.

    Raises
    ------
    InputError
        Unknown subject, site index out of range, the site's chunk not done or damaged.
    """
    store = store_location(store)
    attrs = check_store(store)
    g = _subject_group(store, subject_id, attrs)
    _check_site(g, subject_id, site_index)
    site = int(site_index)
    mesh = read_mesh(store, g.attrs["mesh_id"])
    reader = SubjectReader(store, subject_id, int(attrs["schema_version"]))  # checksums, fingerprint, finite u
    u = np.asarray(reader.rows("u", [site])[0], np.float32)  # (time, node)
    where = f"subject {subject_id}"
    static = {
        "activation_ms": (reader.rows("activation", [site])[0] * MS_PER_TIME_UNIT).astype(np.float32),
        "a": np.asarray(read_checked(g, "a", store, where), np.float32),
        "label": np.asarray(read_checked(g, "label", store, where), np.int8),
    }
    frames = {"V_mV": to_millivolts(u), "u": u}
    times_ms = read_checked(g, "times", store, where) * MS_PER_TIME_UNIT
    return write_time_series(out_dir, f"{subject_id}_site{site:04d}", mesh.points, mesh.cells, times_ms, frames, static)
