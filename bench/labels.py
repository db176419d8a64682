"""Detected node sets against the labels of public labelled meshes: share of each label's nodes tagged right.

For each labelled mesh (:data:`LABELLED`: the files of ``tests/data/labelled/``, the shipped
meshes whose files carry labels, the procedural meshes with their own sets), at its own
resolution and resampled to each ``--nodes`` count (:func:`simgen.meshes.resample.resample`,
triangles; the labels move with the surface, each new node taking its nearest old node's), the
node sets are detected afresh (:func:`simgen.meshes.nodesets.detect_heart`, ignoring the
labels) and compared with the labels (:func:`simgen.meshes.labels.label_agreement`): the share
of each label's surface nodes tagged with it, ``near`` (a node one surface edge from another
label may count for either) and, in brackets, strictly (only the node's own labels, which
nodes on the line between two facet labels have both of).

Run::

    .venv/bin/python -m bench.labels --out report/bench   # about 2 min on a 2-core VM
    .venv/bin/python -m bench.labels --nodes 1000 --meshes ldrb-patient-lv
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import meshio
import numpy as np

from bench.common import add_out_argument, machine, write_out
from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.io import load_mesh
from simgen.meshes.labels import label_agreement
from simgen.meshes.nodesets import detect_heart
from simgen.meshes.resample import resample
from simgen.meshes.shipped import unpacked

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "labelled"
#: Surface ids of PyAnsys Heart's case-01 LV (its ``heart_model.partinfo.json``): epicardium, endocardium.
RODERO_SURFACES = {34721: "epicardium", 34722: "endocardium"}
NODES = (1000, 2000, 5000)


def data_mesh(name: str) -> Mesh:
    """A mesh of ``tests/data/labelled/`` (gzip-compressed) read with its labels."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        with gzip.open(DATA / f"{name}.gz", "rb") as src, path.open("wb") as dst:
            shutil.copyfileobj(src, dst)
        return load_mesh(path)


def shipped_mesh(name: str) -> Mesh:
    """A shipped real mesh as it is, with the labels its file carries."""
    with unpacked(f"real:{name}") as path:
        return load_mesh(path, units="mm")


def rodero_mesh() -> Mesh:
    """The shipped Rodero LV with its epicardium and endocardium from the file's ``_surface-id`` triangles."""
    with unpacked("real:rodero01-lv") as path:
        raw, mesh = meshio.read(path), load_mesh(path, units="mm")
    block = next(i for i, b in enumerate(raw.cells) if b.type == "triangle")
    ids = np.asarray(raw.cell_data["_surface-id"][block])
    sets = {name: mesh.from_file(np.unique(raw.cells[block].data[ids == v])) for v, name in RODERO_SURFACES.items()}
    return dataclasses.replace(mesh, node_sets={**mesh.node_sets, **sets})


#: Labelled meshes by name: (what it is, loader of the mesh with its labels as node sets).
LABELLED: dict[str, tuple[str, Callable[[], Mesh]]] = {
    "cobiveco-mean-biv": ("BiV surface, point classes", lambda: shipped_mesh("cobiveco-mean-biv")),
    "cardiac-geometries-biv": ("BiV tetra, gmsh markers", lambda: data_mesh("cardiac_geometries_biv.msh")),
    "ldrb-patient-lv": ("LV tetra, gmsh markers", lambda: data_mesh("ldrb_patient_lv.msh")),
    "cardiac-geometries-lv": ("LV tetra, gmsh markers", lambda: data_mesh("cardiac_geometries_lv.msh")),
    "rodero01-lv": ("LV tetra, surface ids", rodero_mesh),
    "procedural-biv": ("BiV tetra, own sets", lambda: get_mesh("biv", 2000, "tetra")),
    "procedural-lv": ("LV tetra, own sets", lambda: get_mesh("lv", 2000, "tetra")),
}


def agreement(mesh: Mesh, near: bool = True) -> dict[str, float]:
    """Per-label share of ``mesh``'s labelled nodes that detection, blind to the labels, tags right."""
    bare = Mesh(mesh.points, mesh.cells, {"surface": mesh.nodes("surface")}, name=mesh.name)
    detected, _ = detect_heart(bare)
    return label_agreement(mesh, mesh.node_sets, detected, near=near)


def rows(names: list[str], nodes: tuple[int, ...]) -> list[tuple[str, int, str, float, float, float]]:
    """``(mesh, nodes, label, share near, share strict, seconds)`` for each mesh, resolution and label."""
    out = []
    for name in names:
        original = LABELLED[name][1]()
        for target in (None, *nodes):
            start = time.perf_counter()
            mesh = original if target is None else resample(original, target, "triangle")
            near, strict = agreement(mesh), agreement(mesh, near=False)
            seconds = time.perf_counter() - start
            out += [(name, mesh.n_nodes, label, near[label], strict[label], seconds) for label in near]
    return out


def table(found: list[tuple[str, int, str, float, float, float]], nodes: tuple[int, ...]) -> str:
    """Markdown table of :func:`rows`: a row per mesh and label, a column per resolution (``near (strict)``)."""
    header = ["as it is", *(f"~{n:,}" for n in nodes)]
    lines = ["| mesh | label | " + " | ".join(header) + " |", "|---|---|" + "---:|" * len(header)]
    for name in dict.fromkeys(row[0] for row in found):
        mine = [row for row in found if row[0] == name]
        counts = [row[1] for row in mine if row[2] == mine[0][2]]
        lines.append(f"| {name} | nodes | " + " | ".join(f"{n:,}" for n in counts) + " |")
        for label in dict.fromkeys(row[2] for row in mine):
            cells = [f"{near:.1%} ({strict:.1%})" for _, _, lab, near, strict, _ in mine if lab == label]
            lines.append(f"| | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", default=",".join(map(str, NODES)), help="resampled node counts, comma-separated")
    parser.add_argument("--meshes", default=",".join(LABELLED), help=f"of {', '.join(LABELLED)}")
    add_out_argument(parser, "labels")
    args = parser.parse_args(argv)
    nodes = tuple(int(n) for n in args.nodes.split(",") if n)
    found = rows(args.meshes.split(","), nodes)
    markdown = table(found, nodes)
    print(markdown)
    worst = min(found, key=lambda row: row[3])
    print(f"\nlowest: {worst[3]:.1%} ({worst[2]} of {worst[0]} at {worst[1]:,} nodes)")
    write_out(args.out, "labels", markdown, {"machine": machine(), "rows": [list(map(str, r)) for r in found]})


if __name__ == "__main__":
    main()
