"""Mesh sources by name: procedural geometries, shipped real meshes or a mesh file."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.biventricular import biv_ellipsoid
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.heart import load_heart
from simgen.meshes.shapes import shape_from_params
from simgen.meshes.shipped import REAL_MESHES, REAL_PREFIX, is_real, real_mesh_file

__all__ = ["GENERATORS", "DEFAULT_NODES", "get_mesh", "source_file"]

#: Procedural geometries, each ``f(n_nodes, kind, name=...) -> Mesh``.
GENERATORS = {"lv": lv_ellipsoid, "biv": biv_ellipsoid}

#: Node count of a procedural geometry when none is given.
DEFAULT_NODES = 2000


def get_mesh(
    source: str,
    n_nodes: int | None = None,
    kind: Literal["tetra", "triangle"] | None = None,
    name: str | None = None,
    shape_params: dict[str, Any] | None = None,
    units: str | None = None,
    landmarks: Mapping[str, Sequence[float]] | None = None,
    node_set_arrays: Mapping[str, str] | None = None,
    heart: bool = True,
    filler: str | None = None,
) -> Mesh:
    """A procedural geometry (``"lv"``, ``"biv"``), a shipped real mesh (``"real:<name>"``) or a mesh file.

    Procedural geometries have about ``n_nodes`` nodes (default
    :data:`DEFAULT_NODES`) of cell ``kind`` (default tetrahedra);
    ``shape_params`` (:func:`~simgen.meshes.shapes.shape_from_params`;
    ``None``: the default geometry) apply to them only. Real meshes and files
    go through :func:`~simgen.meshes.heart.load_heart` (units, repair,
    resampling to ``n_nodes`` and ``kind``, node sets and axis), which
    ``units``, ``landmarks`` and ``node_set_arrays`` steer; without
    ``n_nodes`` they are used as they are (their own node ids and cells). A
    file that is no heart is refused unless ``heart=False``. ``filler``: how a surface is filled with
    tetrahedra (:data:`~simgen.meshes.fillers.FILLERS`; ``None``: ``"auto"``).
    """
    if source in GENERATORS:
        if units is not None or landmarks or node_set_arrays or not heart or filler is not None:
            raise MeshError(
                f"procedural mesh {source!r} takes no units, landmarks, node_set_arrays, filler or heart = false "
                "(files do)"
            )
        n_nodes, kind = n_nodes or DEFAULT_NODES, kind or "tetra"
        geometry = None if shape_params is None else shape_from_params(source, shape_params).geometry()
        return GENERATORS[source](n_nodes, kind, geometry=geometry, name=name or f"{source}-{kind}-{n_nodes}")
    if shape_params is not None:
        raise MeshError(f"mesh file {source!r} takes no shape parameters (only {sorted(GENERATORS)} do)")
    path = source_file(source)
    if path is None or not path.exists():
        raise MeshError(
            f"unknown mesh {source!r}: use one of {sorted(GENERATORS)}, a shipped mesh "
            f"{[REAL_PREFIX + n for n in REAL_MESHES]} or the path of an existing mesh file"
        )
    name = name or Path(source).stem
    return load_heart(source, n_nodes, kind, name, units, landmarks, node_set_arrays, heart, filler)


def source_file(source: str) -> Path | None:
    """The file behind a mesh source: a shipped mesh's compressed file, a file path, ``None`` for procedural ones."""
    if source in GENERATORS:
        return None
    if is_real(source):
        return real_mesh_file(source)
    path = Path(source)
    return path if path.suffix else None
