"""Mesh sources by name: procedural geometries or a mesh file."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.biventricular import biv_ellipsoid
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.io import load_mesh
from simgen.meshes.shapes import shape_from_params

__all__ = ["GENERATORS", "get_mesh"]

#: Procedural geometries, each ``f(n_nodes, kind, name=...) -> Mesh``.
GENERATORS = {"lv": lv_ellipsoid, "biv": biv_ellipsoid}


def get_mesh(
    source: str,
    n_nodes: int = 2000,
    kind: Literal["tetra", "triangle"] = "tetra",
    name: str | None = None,
    shape_params: dict[str, Any] | None = None,
) -> Mesh:
    """A procedural geometry (``"lv"``, ``"biv"``) with ``n_nodes`` nodes, or a mesh file path.

    Files are loaded with meshio and validated; ``n_nodes``, ``kind`` and
    ``shape_params`` (:func:`~simgen.meshes.shapes.shape_from_params`; ``None``:
    the default geometry) apply to procedural geometries only.
    """
    if source in GENERATORS:
        geometry = None if shape_params is None else shape_from_params(source, shape_params).geometry()
        return GENERATORS[source](n_nodes, kind, geometry=geometry, name=name or f"{source}-{kind}-{n_nodes}")
    if shape_params is not None:
        raise MeshError(f"mesh file {source!r} takes no shape parameters (only {sorted(GENERATORS)} do)")
    path = Path(source)
    if path.suffix and path.exists():
        return load_mesh(path, name=name or path.stem)
    raise MeshError(f"unknown mesh {source!r}: use one of {sorted(GENERATORS)} or the path of an existing mesh file")
