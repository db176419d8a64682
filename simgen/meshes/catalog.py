"""Mesh sources by name: procedural geometries or a mesh file."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.biventricular import biv_ellipsoid
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.io import load_mesh

__all__ = ["GENERATORS", "get_mesh"]

#: Procedural geometries, each ``f(n_nodes, kind, name=...) -> Mesh``.
GENERATORS = {"lv": lv_ellipsoid, "biv": biv_ellipsoid}


def get_mesh(
    source: str, n_nodes: int = 2000, kind: Literal["tetra", "triangle"] = "tetra", name: str | None = None
) -> Mesh:
    """A procedural geometry (``"lv"``, ``"biv"``) with ``n_nodes`` nodes, or a mesh file path.

    Files are loaded with meshio and validated; ``n_nodes`` and ``kind`` apply
    to procedural geometries only.
    """
    if source in GENERATORS:
        return GENERATORS[source](n_nodes, kind, name=name or f"{source}-{kind}-{n_nodes}")
    path = Path(source)
    if path.suffix and path.exists():
        return load_mesh(path, name=name or path.stem)
    raise MeshError(
        f"unknown mesh {source!r}: use one of {sorted(GENERATORS)} or the path of an existing mesh file"
    )
