"""Benchmark: one heart, one answer at any resolution. The simulator under mesh refinement.

Every heart (the procedural LV and BiV, every shipped real heart) is meshed at
``--nodes`` (default 1k, 2k, 5k, 10k, 20k) and simulated under each
``--tissue`` setting (default healthy and the three scars of the shipped
model's training data) from the same ``--sites`` pacing positions: points of
the finest mesh's epicardium chosen by farthest-point sampling, each paced on
every mesh by a stimulus centred on the point (its site the nearest node).
Solver settings are the defaults (``--radius``
overrides the stimulus radius, ``--legacy`` runs the edge-path patch of 1.5
mean edge lengths that stores built before the radius was in mm use).

Each run is compared with the finest mesh's, whose ``u`` and activation times
are interpolated (P1, :func:`shared.interpolation.interpolation_matrix`) onto
the coarser mesh's nodes:

* capture: whether each site starts a wave (:mod:`shared.capture`) at this
  resolution and at the finest; a row's ``capture`` column counts the sites
  that start one, and ``flips`` those where the two disagree;
* spatial CC of ``u`` (per frame over the nodes, mean over the frames), per
  site, over the sites that start a wave on both meshes (a flip is counted
  above, not scored twice): the smallest and the mean;
* activation-time error in ms over the same sites: per site the mean
  ``|t - t_finest|`` over the nodes activated in both; the mean over the
  sites and the worst site.

The summary gives, per resolution, the worst of these over every heart and
tissue setting, and the resolution from which the goals hold: no capture
flip anywhere, and from there up CC >= 0.95 and mean activation error <= 5 ms.

Run::

    .venv/bin/python -m bench.convergence --out report/bench              # ~15 min on 2 cores
    .venv/bin/python -m bench.convergence --hearts lv --nodes 1000 2000 5000 --tissue healthy

Meshes are cached in ``--cache`` (default ``report/bench/convergence-meshes``;
the real hearts' 20k-node fills take about a minute each).
"""

from __future__ import annotations

import argparse
import pickle
import time
from pathlib import Path

import numpy as np

from bench.common import add_out_argument, machine, machine_line, write_out
from learner.metrics import frame_cc
from shared.capture import started_wave
from shared.interpolation import interpolation_matrix
from shared.mesh import Mesh
from shared.sites import nearest_nodes
from shared.units import MS_PER_TIME_UNIT
from simgen.meshes import get_mesh
from simgen.meshes.shipped import REAL_MESHES, REAL_PREFIX
from simgen.observe.sock import farthest_point_sampling
from simgen.solver.simulate import Simulator, SolverConfig
from simgen.tissue import default_settings, tissue_fields

HEARTS = ("lv", "biv", *(REAL_PREFIX + name for name in REAL_MESHES))
TISSUES = ("healthy", "scar-anterior-mid", "scar-septal-basal", "scar-inferior-apical")
#: The goals: from the converged resolution up, the smallest CC and the largest mean activation error (ms).
GOAL_CC, GOAL_ERROR_MS = 0.95, 5.0


def cached_mesh(source: str, nodes: int, cache: Path) -> tuple[Mesh, float]:
    """The mesh of ``source`` at ``nodes`` nodes, from ``cache`` when there; and the seconds it took to make."""
    path = cache / f"{source.replace(':', '_')}-{nodes}.pkl"
    if path.exists():
        with path.open("rb") as f:
            return pickle.load(f)
    start = time.perf_counter()
    mesh = get_mesh(source, nodes, "tetra")
    made = (mesh, time.perf_counter() - start)
    cache.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        pickle.dump(made, f)
    return made


def pacing_positions(mesh: Mesh, count: int) -> np.ndarray:
    """``count`` epicardial points of ``mesh`` (mm) spread by farthest-point sampling from the epicardium's
    node nearest its centroid."""
    epi = mesh.points[mesh.nodes("epicardium")]
    start = int(np.argmin(np.linalg.norm(epi - epi.mean(axis=0), axis=1)))
    return epi[farthest_point_sampling(epi, count, start)]


def compare(coarse: Mesh, run, fine: Mesh, reference) -> dict:
    """One resolution's run against the finest one's, interpolated onto ``coarse``'s nodes (module docstring)."""
    weights = interpolation_matrix(fine.points, fine.cells, coarse.points)
    never = weights @ np.isnan(reference.activation).T.astype(float) > 0  # (N, S): a stencil node never activates
    captured, captured_fine = started_wave(run.activated_fraction), started_wave(reference.activated_fraction)
    ccs, errors = [], []
    for s in range(len(run.sites)):
        if not (captured[s] and captured_fine[s]):
            continue  # a flip is counted as such; no wave on either mesh has no front to compare
        truth = (weights @ reference.u[s].T).T
        ccs.append(float(np.nanmean(frame_cc(run.u[s], truth))))
        t_fine = weights @ np.nan_to_num(reference.activation[s])
        both = np.isfinite(run.activation[s]) & ~never[:, s]
        errors.append(float(np.abs(run.activation[s][both] - t_fine[both]).mean()) * MS_PER_TIME_UNIT)
    return {
        "capture": int(captured.sum()),
        "flips": int((captured != captured_fine).sum()),
        "activated": [round(float(f), 3) for f in run.activated_fraction],
        "cc_min": min(ccs, default=float("nan")),
        "cc_mean": float(np.mean(ccs)) if ccs else float("nan"),
        "error_mean_ms": float(np.mean(errors)) if errors else float("nan"),
        "error_worst_ms": max(errors, default=float("nan")),
    }


def heart_rows(source: str, args: argparse.Namespace) -> list[dict]:
    """Every tissue setting and resolution of one heart, compared with its finest mesh."""
    meshes = {nodes: cached_mesh(source, nodes, args.cache) for nodes in args.nodes}
    finest = max(args.nodes)
    positions = pacing_positions(meshes[finest][0], args.sites)
    settings = {s.name: s for s in default_settings()}
    config = SolverConfig(stimulus_radius=args.radius)
    rows = []
    for tissue in args.tissue:
        runs = {}
        for nodes, (mesh, _) in meshes.items():
            config_here = config
            if args.legacy:
                config_here = SolverConfig(stimulus_radius=1.5 * mesh.mean_edge_length(), stimulus_region="geodesic")
            sites = nearest_nodes(mesh.points, positions, np.inf)  # the node nearest each pacing point
            start = time.perf_counter()
            sim = Simulator(mesh, tissue_fields(mesh, settings[tissue]), config_here)
            centres = None if args.legacy else positions  # the legacy patch starts at a node
            run = sim.run(sites, threads=args.threads, centres=centres)
            runs[nodes] = (run, time.perf_counter() - start, sim.stimulus_radius)
        fine_mesh, reference = meshes[finest][0], runs[finest][0]
        for nodes, (mesh, made) in meshes.items():
            run, seconds, radius = runs[nodes]
            row = {
                "heart": source,
                "tissue": tissue,
                "target": nodes,
                "nodes": mesh.n_nodes,
                "edge_mm": round(mesh.mean_edge_length(), 2),
                "radius_mm": round(radius, 2),
                "mesh_s": round(made, 1),
                "simulate_s": round(seconds, 2),
                "sites": len(run.sites),
            }
            if nodes == finest:
                row.update(capture=int(run.started_wave.sum()), flips=0)
            else:
                row.update(compare(mesh, run, fine_mesh, reference))
            rows.append(row)
            print(_row_line(row), flush=True)
    return rows


def _row_line(row: dict) -> str:
    cells = [row["heart"], row["tissue"], str(row["nodes"]), f"{row['edge_mm']:.2f}", f"{row['radius_mm']:.1f}"]
    cells.append(f"{row['capture']}/{row['sites']}")
    cells.append(str(row["flips"]))
    if "cc_min" in row:
        cells += [f"{row['cc_min']:.3f}", f"{row['cc_mean']:.3f}", f"{row['error_mean_ms']:.1f}"]
        cells.append(f"{row['error_worst_ms']:.1f}")
    else:
        cells += ["(finest)", "", "", ""]
    return "| " + " | ".join(cells) + " |"


def summary(rows: list[dict], resolutions: list[int]) -> tuple[list[str], int | None]:
    """Per resolution the worst figures over every heart and tissue, and the converged resolution (or None)."""
    lines = [
        "| target nodes | capture flips | smallest CC | largest mean activation error (ms) | worst site (ms) |",
        "|---|---:|---:|---:|---:|",
    ]
    ok = {}
    for nodes in resolutions[:-1]:
        here = [r for r in rows if r["target"] == nodes]
        flips = sum(r["flips"] for r in here)
        cc = min(r["cc_min"] for r in here)
        error = max(r["error_mean_ms"] for r in here)
        worst = max(r["error_worst_ms"] for r in here)
        ok[nodes] = flips == 0 and cc >= GOAL_CC and error <= GOAL_ERROR_MS
        lines.append(f"| {nodes} | {flips} | {cc:.3f} | {error:.1f} | {worst:.1f} |")
    converged = None
    for nodes in reversed(resolutions[:-1]):
        if not ok[nodes]:
            break
        converged = nodes
    return lines, converged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hearts", nargs="+", default=list(HEARTS), help="mesh sources (lv, biv, real:NAME)")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 2000, 5000, 10_000, 20_000])
    parser.add_argument("--tissue", nargs="+", default=list(TISSUES), help="default tissue setting names")
    parser.add_argument("--sites", type=int, default=6, help="pacing positions per heart")
    parser.add_argument("--radius", type=float, default=None, help="stimulus radius in mm (default: the solver's)")
    parser.add_argument("--legacy", action="store_true", help="edge-path patches of 1.5 mean edges, as old stores")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path("report/bench/convergence-meshes"))
    add_out_argument(parser, "convergence")
    args = parser.parse_args()
    args.nodes = sorted(args.nodes)
    header = (
        "| heart | tissue | nodes | mean edge (mm) | stimulus radius (mm) | capture | flips | CC min | CC mean "
        "| activation error mean (ms) | worst site (ms) |"
    )
    print(f"{machine_line()}; {args.sites} pacing positions per heart, compared with {args.nodes[-1]} nodes")
    print(header + "\n|" + "---|" * 11)
    start = time.perf_counter()
    rows = [row for heart in args.hearts for row in heart_rows(heart, args)]
    lines, converged = summary(rows, args.nodes)
    stated = f"converged from {converged} nodes" if converged else "no resolution meets the goals"
    text = "\n".join(
        [
            f"Machine: {machine_line()}. {len(args.hearts)} hearts x {len(args.tissue)} tissue settings x "
            f"{args.sites} pacing positions, each resolution against {args.nodes[-1]} nodes; "
            f"{time.perf_counter() - start:.0f} s.",
            "",
            header,
            "|" + "---|" * 11,
            *map(_row_line, rows),
            "",
            *lines,
            "",
            f"Goals: no capture flip, CC >= {GOAL_CC}, mean activation error <= {GOAL_ERROR_MS:g} ms: {stated}.",
        ]
    )
    print("\n" + "\n".join(lines) + f"\n\n{stated}")
    write_out(args.out, "convergence", text + "\n", {"machine": machine(), "rows": rows, "converged": converged})


if __name__ == "__main__":
    main()
