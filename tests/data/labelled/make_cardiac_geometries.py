"""Regenerate the two cardiac-geometries meshes of this folder (not run by the tests).

Needs the PyPI packages ``cardiac-geometries-core`` (MIT, Henrik Finsberg) and ``gmsh``
(GPL-2.0-or-later with a linking exception; only run here, nothing of it is shipped):

    python -m venv /tmp/cg && /tmp/cg/bin/pip install cardiac-geometries-core==1.5.0 gmsh==4.15.2
    /tmp/cg/bin/python tests/data/labelled/make_cardiac_geometries.py

Each mesh is written as gmsh writes it, then gzip-compressed. Units: the BiV in cm, the LV in m
(the packages' defaults; simgen infers them).
"""

from __future__ import annotations

import gzip
import shutil
import tempfile
from pathlib import Path

import cardiac_geometries_core as cgc

HERE = Path(__file__).parent


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        made = {
            "cardiac_geometries_biv.msh": cgc.biv_ellipsoid(Path(folder) / "biv.msh", char_length=0.5),
            "cardiac_geometries_lv.msh": cgc.lv_ellipsoid(Path(folder) / "lv.msh", psize_ref=0.008),
        }
        for name, path in made.items():
            with open(path, "rb") as src, gzip.GzipFile(HERE / f"{name}.gz", "wb", mtime=0) as dst:
                shutil.copyfileobj(src, dst)


if __name__ == "__main__":
    main()
