"""Real, imaging-derived heart meshes shipped with simgen (``simgen/meshes/real/``), by name.

Each is the source file as published, gzip-compressed, in millimetres; its
origin and licence are in ``simgen/meshes/real/SOURCES.md``. A build spec or
:func:`simgen.meshes.get_mesh` names one as ``"real:<name>"``.
"""

from __future__ import annotations

import gzip
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from shared.errors import MeshError

__all__ = ["REAL_PREFIX", "REAL_MESHES", "REAL_LANDMARKS", "REAL_DIR", "is_real", "real_mesh_file", "unpacked"]

REAL_PREFIX = "real:"
REAL_DIR = Path(__file__).parent / "real"

#: Shipped meshes: name -> (file in ``real/``, what it is).
REAL_MESHES: dict[str, tuple[str, str]] = {
    "rodero01-lv": ("pyansys_rodero01_lv_tet.vtu.gz", "LV, tetrahedra, valve openings (Rodero et al. 2021 CT case 01)"),
    "tof-biv": ("tof_biv_surface.vtk.gz", "biventricular closed surface, triangles (tetralogy of Fallot MRI study)"),
    "cobiveco-mean-biv": (
        "cobiveco_geo1_ssm_mean_surface.vtu.gz",
        "biventricular closed surface, triangles (mean of a statistical shape model)",
    ),
}


#: Long-axis landmarks of each shipped mesh (mm): the axis detected on the mesh resampled to 20,000 nodes
#: (:func:`simgen.meshes.nodesets.detect_heart`; ``septum`` 30 mm from the base along angle 0). Every
#: resolution of a shipped mesh takes this one frame, so its AHA segments, and the scars placed on them, stay
#: where they are: detected anew on each resampled mesh the axis moves by up to 3 mm and 3 degrees.
REAL_LANDMARKS: dict[str, dict[str, tuple[float, float, float]]] = {
    "rodero01-lv": {"apex": (122.7, 26.5, 4.5), "base": (81.3, 83.0, 69.2), "septum": (108.3, 91.6, 79.0)},
    "tof-biv": {"apex": (-12.1, -8.3, -72.4), "base": (6.9, 7.3, -1.5), "septum": (-9.5, -15.9, 8.0)},
    "cobiveco-mean-biv": {"apex": (-43.6, -3.3, -51.7), "base": (-44.4, 10.4, 42.7), "septum": (-15.1, 4.0, 43.9)},
}


def is_real(source: str) -> bool:
    """Whether ``source`` names a shipped mesh (``"real:<name>"``)."""
    return source.startswith(REAL_PREFIX)


def real_mesh_file(source: str) -> Path:
    """The compressed file of ``"real:<name>"``; :class:`MeshError` listing the names for an unknown one."""
    name = source.removeprefix(REAL_PREFIX)
    if name not in REAL_MESHES:
        known = [REAL_PREFIX + n for n in REAL_MESHES]
        raise MeshError(f"unknown real mesh {source!r}: use one of {known}")
    return REAL_DIR / REAL_MESHES[name][0]


@contextmanager
def unpacked(source: str) -> Iterator[Path]:
    """``with unpacked("real:<name>") as path:`` the shipped mesh decompressed into a temporary folder."""
    packed = real_mesh_file(source)
    with tempfile.TemporaryDirectory(prefix="simgen-real-") as folder:
        path = Path(folder) / packed.name.removesuffix(".gz")
        with gzip.open(packed, "rb") as src, path.open("wb") as dst:
            shutil.copyfileobj(src, dst)
        yield path
