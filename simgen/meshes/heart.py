"""Mesh files made simulation-ready hearts: units, repair, resampling, node sets and long axis.

:func:`load_heart` is what :func:`simgen.meshes.get_mesh` does with a mesh
file or a shipped real mesh (``"real:<name>"``):

1. :func:`~simgen.meshes.io.load_mesh`: millimetres, safe repairs, validation;
   a heart of no plausible size (:func:`check_heart_size`) or whose surface
   passes through itself (:func:`~simgen.meshes.folds.refuse_folds`) is refused;
2. :func:`~simgen.meshes.resample.resample` to about ``nodes`` nodes of ``kind``;
   without ``nodes`` the mesh is used as it is: its own nodes and cells, node
   ids as in the file (:attr:`shared.mesh.Mesh.file_index` maps them back
   where the repairs dropped nodes in no cell); fibres the file carries (point
   data ``fibre``) follow, a resampled node taking its nearest file node's;
3. the node sets the file carries (its own masks, those ``node_set_arrays``
   names, or its labels: facet markers, a class per node,
   :mod:`~simgen.meshes.labels`) are kept, and the long axis taken from them
   (:func:`~simgen.meshes.nodesets.labelled_axis`) when the file has none;
   when it lacks ``epicardium`` or ``endocardium``, all heart sets and the
   long axis are detected (:func:`~simgen.meshes.nodesets.detect_heart`),
   the file's sets taking precedence. A mesh in which no cavity is found (a
   slab, a solid) is no heart and refused, unless ``heart=False`` accepts it
   as it is: its own sets only, nothing detected;
4. ``landmarks`` (``apex``, ``base`` and optionally ``septum`` points in mm)
   replace the detected long axis; a shipped mesh takes its own
   (:data:`~simgen.meshes.shipped.REAL_LANDMARKS`) unless others are given.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from shared.errors import MeshError
from shared.mesh import PLAUSIBLE_HEART_MM, CellType, LongAxis, Mesh
from simgen.meshes.ellipsoid import check_mesh_request
from simgen.meshes.folds import refuse_folds
from simgen.meshes.io import load_mesh
from simgen.meshes.nodesets import detect_heart, labelled_axis
from simgen.meshes.resample import resample
from simgen.meshes.shipped import REAL_LANDMARKS, REAL_PREFIX, is_real, unpacked
from simgen.meshes.units import HEART_EXTENT_MM, UNITS_HINT
from simgen.meshes.validate import refuse_parts, validate_mesh

__all__ = ["LANDMARKS", "load_heart", "axis_from_landmarks"]

log = logging.getLogger("simgen.meshes")

#: Landmark points a spec may give (mm); ``apex`` and ``base`` (base centre) are required together.
LANDMARKS = ("apex", "base", "septum")


def check_heart_size(mesh: Mesh, source: str) -> None:
    """Refuse a heart whose size in mm no heart has: a length unit given or declared wrongly."""
    extent = float(np.ptp(mesh.points, axis=0).max())
    lo, hi = PLAUSIBLE_HEART_MM
    if not lo <= extent <= hi:
        refuse_parts(mesh.cells, mesh.n_nodes, source)  # pieces far apart are no unit's mistake
        raise MeshError(
            f"{source}: read as a heart {extent:.4g} mm across, and hearts span about {HEART_EXTENT_MM[0]:g}-"
            f"{HEART_EXTENT_MM[1]:g} mm: its length unit is wrong (the file's own, or the one given); "
            f"give the unit its coordinates are in: {UNITS_HINT}"
        )


def load_heart(
    source: str | PathLike,
    nodes: int | None,
    kind: CellType | None,
    name: str | None = None,
    units: str | None = None,
    landmarks: Mapping[str, Sequence[float]] | None = None,
    node_set_arrays: Mapping[str, str] | None = None,
    heart: bool = True,
    filler: str | None = None,
) -> Mesh:
    """A mesh file or ``"real:<name>"`` as a validated heart mesh of about ``nodes`` nodes (module docstring).

    Raises :class:`MeshError` naming the mesh when its heart node sets cannot
    be detected; ``heart=False`` accepts a mesh that is no heart (a slab for
    tests and verification) without detecting anything. ``filler``: the
    tetrahedral filler of a resampling to tetrahedra
    (:data:`~simgen.meshes.fillers.FILLERS`); a surface that passes through
    itself (merged from overlapping parts) is accepted only to be filled by
    fTetWild, which rebuilds it.
    """
    if is_real(str(source)):
        landmarks = landmarks or REAL_LANDMARKS.get(str(source).removeprefix(REAL_PREFIX))
        with unpacked(str(source)) as path:
            mesh = load_mesh(
                path,
                name or str(source).removeprefix(REAL_PREFIX),
                units=units or "mm",
                node_set_arrays=node_set_arrays,
            )
    else:
        mesh = load_mesh(Path(source), name, units=units, node_set_arrays=node_set_arrays, heart=heart)
    refilled = nodes is not None and (kind or mesh.cell_type) == "tetra" and filler in (None, "auto", "ftetwild")
    if heart:
        check_heart_size(mesh, str(source))
        if not refilled:
            refuse_folds(mesh, str(source))
    if nodes is not None:
        check_mesh_request(kind or mesh.cell_type, nodes, 200)  # the range of the procedural meshes
        original, mesh = mesh, resample(mesh, nodes, kind or mesh.cell_type, filler)
        if original.fibres is not None:  # each new node takes the fibre (and sheet) of the file's nearest node
            nearest = cKDTree(original.points).query(mesh.points)[1]
            sheets = None if original.sheets is None else original.sheets[nearest]
            mesh = dataclasses.replace(mesh, fibres=original.fibres[nearest], sheets=sheets)
    elif kind is not None and kind != mesh.cell_type:
        raise MeshError(
            f"{source} holds {mesh.cell_type}s: used as it is, it is simulated as {mesh.cell_type}s; to have "
            f"{kind}s, give a node count to resample it to (--nodes N; resampling renumbers its nodes)"
        )
    sets, axis = dict(mesh.node_sets), mesh.axis
    if heart and {"epicardium", "endocardium"} <= set(sets) and axis is None:
        axis = _labelled_axis(mesh)
    if heart and ("epicardium" not in sets or "endocardium" not in sets):
        try:
            detected, axis = detect_heart(mesh)
        except MeshError as exc:
            raise MeshError(
                f"{source}: not a heart, its heart node sets (epicardium, endocardium, base) cannot be detected: "
                f"{exc}; to simulate a mesh that is no heart (a slab), accept it with `heart = false` in its "
                "[[meshes]] entry (`--no-heart` on the command line)"
            ) from None
        sets = {**detected, **sets}
    if landmarks:
        axis = axis_from_landmarks(landmarks, axis)
    return validate_mesh(dataclasses.replace(mesh, node_sets=sets, axis=axis))


def _labelled_axis(mesh: Mesh) -> LongAxis | None:
    """The long axis of the file's own node sets; ``None`` (as before they were read) if they give none."""
    try:
        return labelled_axis(mesh)
    except MeshError as exc:
        log.info("%s: no long axis from its node sets: %s", mesh.name, exc)
        return None


def axis_from_landmarks(landmarks: Mapping[str, Sequence[float]], detected: LongAxis | None = None) -> LongAxis:
    """The long axis through ``apex`` and ``base``; angle 0 towards ``septum``, else the detected one, else x."""
    unknown = sorted(set(landmarks) - set(LANDMARKS))
    if unknown or not {"apex", "base"} <= set(landmarks):
        raise MeshError(f"axis landmarks: give apex and base (and optionally septum), got {sorted(landmarks)}")
    points = {}
    for key, value in landmarks.items():
        point = np.asarray(value, dtype=np.float64)
        if point.shape != (3,) or not np.isfinite(point).all():
            raise MeshError(f"axis landmark {key!r} must be 3 finite coordinates (mm), got {list(value)}")
        points[key] = point
    d = points["base"] - points["apex"]
    if np.linalg.norm(d) == 0:
        raise MeshError("axis landmarks: apex and base coincide")
    d /= np.linalg.norm(d)
    if "septum" in points:
        towards = points["septum"] - points["apex"]
    elif detected is not None:
        towards = np.asarray(detected.reference, dtype=np.float64)
    else:
        towards = np.eye(3)[0 if abs(d[0]) < np.sqrt(0.5) else 1]
    reference = towards - (towards @ d) * d
    if np.linalg.norm(reference) < 1e-9:
        raise MeshError("axis landmarks: the septum point lies on the long axis")
    return LongAxis(points["apex"], points["base"], reference / np.linalg.norm(reference))
