"""Benchmark: tetrahedral fills with fTetWild and TetGen, on clean surfaces and on one that crosses itself.

Rows:

* ``merged``: the boundaries of two procedural LVs (3,000 nodes each), one moved 25 mm sideways,
  concatenated into one triangle soup whose walls cross, as a surface merged from parts does;
  TetGen refuses it, fTetWild (the ``auto`` choice) fills it at each of ``--nodes``;
* ``merged BiV``: a biventricle merged from three closed parts that overlap at the septum and the
  valves (:func:`merged_biv`: an LV, an RV made from a narrower LV moved onto its septum, and a
  valve-plane ball across both bases), filled at each of ``--nodes`` the same way;
* every shipped real heart and the procedural LV and BiV surfaces at 2,000 nodes, with both fillers.

Per row: the nodes reached against the target, the wall time of :func:`simgen.meshes.resample.resample`
(the fill with its node-count fitting), the smallest dihedral angle and radius ratio, and the volume
against that of the surface it fills (for ``merged``, of the union of the two LVs, :func:`union_volume`).

Run::

    .venv/bin/python -m bench.fill --out report/bench

``--publish`` writes the table into the block ``fill`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from bench.common import add_out_argument, add_publish_argument, check_publish, machine, publish_out, write_out
from shared.errors import MeshError
from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fillers import tetgen_available
from simgen.meshes.quality import mesh_quality
from simgen.meshes.resample import resample
from simgen.meshes.shipped import REAL_MESHES, REAL_PREFIX
from simgen.meshes.topology import extract_surface, signed_volumes

__all__ = ["merged_surface", "union_volume", "merged_biv", "biv_union_volume", "main"]

#: How far the second LV of the merged surface is moved (mm): its walls cross the first's.
SHIFT = 25.0
#: The parts of :func:`merged_biv` besides the LV: the RV as the LV scaled per axis and moved (mm), and the
#: valve-plane ball (centre and radius, mm) across both bases.
RV_SCALE, RV_SHIFT = np.array([0.8, 1.1, 0.8]), np.array([35.0, 0.0, 3.0])
VALVES, VALVE_RADIUS = np.array([17.0, 0.0, 14.0]), 16.0


def merged_surface(nodes: int = 3000, shift: float = SHIFT) -> Mesh:
    """The boundaries of two procedural LVs of about ``nodes`` nodes, the second moved ``shift`` mm along x, as
    one triangle soup whose walls cross where they overlap."""
    surface = extract_surface(get_mesh("lv", nodes, kind="tetra"))
    moved = surface.points + np.array([shift, 0.0, 0.0])
    points = np.vstack([surface.points, moved])
    return Mesh(points, np.vstack([surface.cells, surface.cells + len(surface.points)]), name="merged")


def merged_biv(nodes: int = 3000) -> Mesh:
    """A biventricle merged from three closed parts whose walls cross (module docstring), one triangle soup."""
    lv = extract_surface(get_mesh("lv", nodes, kind="tetra"))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=VALVE_RADIUS)
    parts = [(lv.points, lv.cells), (lv.points * RV_SCALE + RV_SHIFT, lv.cells), (ball.vertices + VALVES, ball.faces)]
    offsets = np.cumsum([0] + [len(p) for p, _ in parts[:-1]])
    points = np.vstack([p for p, _ in parts])
    return Mesh(points, np.vstack([t + o for (_, t), o in zip(parts, offsets)]), name="merged-biv")


def biv_union_volume(nodes: int = 3000, samples: int = 40_000, seed: int = 0) -> float:
    """Volume (mm^3) inside any part of :func:`merged_biv`, the share of points drawn uniformly in the parts'
    bounding box inside one of them (Monte Carlo, about 1% at 40,000 points)."""
    lv = get_mesh("lv", nodes, kind="tetra")
    surface = merged_biv(nodes).points
    lo, hi = surface.min(axis=0), surface.max(axis=0)
    points = np.random.default_rng(seed).uniform(lo, hi, (samples, 3))
    inside = _in_lv(lv, points) | _in_lv(lv, (points - RV_SHIFT) / RV_SCALE)
    inside |= np.linalg.norm(points - VALVES, axis=1) <= VALVE_RADIUS
    return float(np.prod(hi - lo) * inside.mean())


def _in_lv(lv: Mesh, points: np.ndarray) -> np.ndarray:
    """Whether each point lies inside the procedural LV ``lv`` (in one of its tetrahedra)."""
    corners = lv.points[lv.cells]
    inside = np.zeros(len(points), bool)
    for candidates in cKDTree(corners.mean(axis=1)).query(points, k=24)[1].T:
        inside |= _in_tets(points, corners[candidates])
    return inside


def union_volume(nodes: int = 3000, shift: float = SHIFT, samples: int = 20_000, seed: int = 0) -> float:
    """Volume (mm^3) inside either LV of :func:`merged_surface`: twice one LV's, less their overlap, the share
    of points drawn uniformly in one LV that also lie in the other (Monte Carlo, about 1% at 20,000 points)."""
    lv = get_mesh("lv", nodes, kind="tetra")
    corners = lv.points[lv.cells]
    volumes = np.abs(signed_volumes(lv.points, lv.cells))
    rng = np.random.default_rng(seed)
    tets = rng.choice(len(volumes), samples, p=volumes / volumes.sum())
    weights = rng.dirichlet(np.ones(4), samples)
    points = np.einsum("sk,skd->sd", weights, corners[tets]) - np.array([shift, 0.0, 0.0])
    return float(volumes.sum() * (2.0 - _in_lv(lv, points).mean()))


def _in_tets(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Whether each point lies in its tetrahedron (``corners`` (S, 4, 3)), by barycentric coordinates."""
    edges = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)
    local = np.linalg.solve(edges, (points - corners[:, 0])[:, :, None])[:, :, 0]
    return (local >= -1e-12).all(axis=1) & (local.sum(axis=1) <= 1 + 1e-12)


def _row(name: str, surface: Mesh, reference_volume: float, nodes: int, filler: str) -> dict:
    row = {"mesh": name, "target": nodes, "filler": filler}
    start = time.perf_counter()
    try:
        mesh = resample(surface, nodes, "tetra", filler)
    except MeshError as exc:
        return {**row, "refused": str(exc).split(":")[-1].strip()[:60]}
    quality = mesh_quality(mesh)
    volume = float(signed_volumes(mesh.points, mesh.cells).sum())
    return {
        **row,
        "nodes": mesh.n_nodes,
        "seconds": time.perf_counter() - start,
        "min_dihedral": quality.min_angle,
        "min_radius_ratio": quality.min_radius_ratio,
        "volume_ratio": volume / reference_volume,
    }


def measure(merged_nodes: list[int], clean_nodes: int) -> list[dict]:
    merged = merged_surface()
    rows = [_row("merged (crossing)", merged, union_volume(), n, "auto") for n in merged_nodes]
    biv, biv_volume = merged_biv(), biv_union_volume()
    rows += [_row("merged BiV (three parts)", biv, biv_volume, n, "auto") for n in merged_nodes]
    sources = ["lv", "biv", *(REAL_PREFIX + name for name in REAL_MESHES)]
    fillers = ("tetgen", "ftetwild") if tetgen_available() else ("ftetwild",)
    for source in sources:
        mesh = get_mesh(source, 8000, "triangle") if source in ("lv", "biv") else get_mesh(source)
        surface = extract_surface(mesh)
        volume = abs(float(trimesh.Trimesh(surface.points, surface.cells, process=False).volume))
        rows += [_row(source, surface, volume, clean_nodes, filler) for filler in fillers]
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| surface | filler | target | nodes | miss | fill (s) | min dihedral (deg) | min radius ratio | volume |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "refused" in r:
            lines.append(f"| {r['mesh']} | {r['filler']} | {r['target']:,} | refused: {r['refused']} | | | | | |")
            continue
        lines.append(
            f"| {r['mesh']} | {r['filler']} | {r['target']:,} | {r['nodes']:,} | {r['nodes'] / r['target'] - 1:+.1%} "
            f"| {r['seconds']:.1f} | {r['min_dihedral']:.1f} | {r['min_radius_ratio']:.3f} | {r['volume_ratio']:.3f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--merged-nodes", type=int, nargs="+", default=[1000, 2000, 5000])
    parser.add_argument("--nodes", type=int, default=2000, help="target of the clean surfaces")
    add_out_argument(parser, "fill")
    add_publish_argument(parser, "fill")
    args = parser.parse_args(argv)
    check_publish(args.publish)
    start = time.perf_counter()
    rows = measure(args.merged_nodes, args.nodes)
    markdown = table(rows)
    print(markdown)
    print(f"({time.perf_counter() - start:.0f} s)")
    write_out(args.out, "fill", markdown, {"machine": machine(), "rows": rows})
    publish_out(args.publish, "fill", markdown)


if __name__ == "__main__":
    main()
