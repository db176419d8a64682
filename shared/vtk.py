"""ParaView time series: one ``.vtu`` per frame and a ``.pvd`` collection listing them with their times in ms.

What ``simgen simulate --vtk``, ``simgen export-vtk`` and ``learner predict --vtk``
write: per frame the potential (``V_mV``, and ``u``) and any other per-frame
field, at every frame the static fields (activation times in ms, tissue, ...).
ParaView opens the whole series from the ``.pvd`` file.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["write_pvd", "write_time_series"]


def write_pvd(path: Path, files: list[str], times_ms: NDArray) -> None:
    """Write a ParaView collection listing ``files`` (relative to ``path``) at ``times_ms``."""
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for name, t in zip(files, times_ms):
        ET.SubElement(collection, "DataSet", timestep=repr(float(t)), group="", part="0", file=name)
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def write_time_series(
    folder: str | Path,
    stem: str,
    points: NDArray,
    cells: NDArray,
    times_ms: NDArray,
    frames: Mapping[str, NDArray],
    static: Mapping[str, NDArray] | None = None,
) -> Path:
    """Write ``<stem>_<frame>.vtu`` per frame and ``<stem>.pvd`` in ``folder``; returns the ``.pvd`` path.

    ``frames``: per-frame point fields ``(T, N)``; ``static``: point fields ``(N,)`` written with every frame.
    Cells with 4 nodes are tetrahedra, with 3 triangles.
    """
    import meshio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cell_type = "tetra" if np.asarray(cells).shape[1] == 4 else "triangle"
    static = {name: np.asarray(value) for name, value in (static or {}).items()}
    files = []
    for frame in range(len(times_ms)):
        name = f"{stem}_{frame:04d}.vtu"
        point_data = {key: np.asarray(value[frame], np.float32) for key, value in frames.items()} | static
        meshio.write(folder / name, meshio.Mesh(points, [(cell_type, cells)], point_data=point_data))
        files.append(name)
    pvd = folder / f"{stem}.pvd"
    write_pvd(pvd, files, times_ms)
    return pvd
