"""Heart meshes: procedural LV / BiV geometries and random anatomies, verification meshes, file I/O, validation."""

from __future__ import annotations

from simgen.meshes.anatomy import Anatomy, sample_anatomies, sample_shapes
from simgen.meshes.biventricular import BiVGeometry, biv_ellipsoid
from simgen.meshes.catalog import GENERATORS, get_mesh
from simgen.meshes.ellipsoid import LVGeometry, lv_ellipsoid
from simgen.meshes.io import load_mesh, save_mesh
from simgen.meshes.shapes import BiVShape, LVShape, shape_from_params
from simgen.meshes.slab import slab, strip
from simgen.meshes.topology import boundary_faces, edge_graph, extract_surface
from simgen.meshes.validate import validate_mesh

__all__ = [
    "Anatomy",
    "sample_anatomies",
    "sample_shapes",
    "BiVGeometry",
    "biv_ellipsoid",
    "GENERATORS",
    "get_mesh",
    "LVGeometry",
    "lv_ellipsoid",
    "load_mesh",
    "save_mesh",
    "BiVShape",
    "LVShape",
    "shape_from_params",
    "slab",
    "strip",
    "boundary_faces",
    "edge_graph",
    "extract_surface",
    "validate_mesh",
]
