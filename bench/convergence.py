"""Benchmark: one heart, one answer at any resolution. The simulator under mesh refinement.

Every heart (the procedural LV and BiV, every shipped real heart) is meshed at
``--nodes`` (default 1k, 2k, 5k, 10k, 20k) and simulated under each
``--tissue`` setting (default healthy and the three scars of the shipped
model's training data) from the same ``--sites`` pacing positions: points of
the finest mesh's epicardium chosen by farthest-point sampling, each paced on
every mesh by a stimulus centred on the point (its site the nearest node).
Solver settings are the defaults (``--radius``
overrides the stimulus radius, ``--legacy`` runs the edge-path patch of 1.5
mean edge lengths that stores built before the radius was in mm use, and
``--scar-border`` another rule of placing scars on the nodes,
:data:`simgen.tissue.fields.SCAR_BORDERS`).

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

from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
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
from simgen.solver.stimulus import IN_SCAR, patch_mask, scar_share
from simgen.tissue import default_settings, tissue_fields
from simgen.tissue.fields import SCAR_BORDERS

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
    """One resolution's run against the finest one's, interpolated onto ``coarse``'s nodes (module docstring):
    per site whether capture flips, and the CC and activation error (NaN unless both meshes start a wave)."""
    weights = interpolation_matrix(fine.points, fine.cells, coarse.points)
    never = weights @ np.isnan(reference.activation).T.astype(float) > 0  # (N, S): a stencil node never activates
    captured, captured_fine = started_wave(run.activated_fraction), started_wave(reference.activated_fraction)
    ccs, errors = np.full(len(run.sites), np.nan), np.full(len(run.sites), np.nan)
    for s in range(len(run.sites)):
        if not (captured[s] and captured_fine[s]):
            continue  # a flip is counted as such; no wave on either mesh has no front to compare
        truth = (weights @ reference.u[s].T).T
        ccs[s] = float(np.nanmean(frame_cc(run.u[s], truth)))
        t_fine = weights @ np.nan_to_num(reference.activation[s])
        both = np.isfinite(run.activation[s]) & ~never[:, s]
        errors[s] = float(np.abs(run.activation[s][both] - t_fine[both]).mean()) * MS_PER_TIME_UNIT
    return {
        "capture": int(captured.sum()),
        "activated": [round(float(f), 3) for f in run.activated_fraction],
        "site_flip": (captured != captured_fine).tolist(),
        "site_cc": [round(float(c), 4) for c in ccs],
        "site_error_ms": [round(float(e), 2) for e in errors],
    }


def figures(row: dict, sites: np.ndarray | None = None) -> dict:
    """A row's flips, smallest and mean CC, mean and worst activation error over ``sites`` (a boolean mask;
    None: every site)."""
    keep = np.ones(len(row["site_cc"]), bool) if sites is None else np.asarray(sites)
    cc, error = np.asarray(row["site_cc"])[keep], np.asarray(row["site_error_ms"])[keep]
    scored = np.isfinite(cc)
    return {
        "flips": int(np.asarray(row["site_flip"])[keep].sum()),
        "cc_min": float(cc[scored].min()) if scored.any() else float("nan"),
        "cc_mean": float(cc[scored].mean()) if scored.any() else float("nan"),
        "error_mean_ms": float(error[scored].mean()) if scored.any() else float("nan"),
        "error_worst_ms": float(error[scored].max()) if scored.any() else float("nan"),
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
            fields = tissue_fields(mesh, settings[tissue], border=args.scar_border)
            sim = Simulator(mesh, fields, config_here)
            centres = None if args.legacy else positions  # the legacy patch starts at a node
            run = sim.run(sites, threads=args.threads, centres=centres)
            runs[nodes] = (run, time.perf_counter() - start, sim.stimulus_radius, fields.label)
        fine_mesh, (reference, _, fine_radius, fine_label) = meshes[finest][0], runs[finest]
        patches = (
            patch_mask(fine_mesh, reference.sites, fine_radius, region="geodesic")
            if args.legacy
            else patch_mask(fine_mesh, reference.sites, fine_radius, centres=positions)
        )
        shares = scar_share(fine_mesh, fine_label, patches)
        for nodes, (mesh, made) in meshes.items():
            run, seconds, radius, _ = runs[nodes]
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
                "site_scar_share": [round(float(x), 3) for x in shares],
            }
            if nodes == finest:
                row.update(capture=int(run.started_wave.sum()), flips=0)
            else:
                row.update(compare(mesh, run, fine_mesh, reference))
                row.update(figures(row))
            rows.append(row)
            print(_row_line(row), flush=True)
    return rows


def _row_line(row: dict) -> str:
    cells = [row["heart"], row["tissue"], str(row["nodes"]), f"{row['edge_mm']:.2f}", f"{row['radius_mm']:.1f}"]
    cells.append(f"{row['capture']}/{row['sites']}")
    cells.append(str(int((~outside_scars(row)).sum())))
    cells.append(str(row["flips"]))
    if "cc_min" in row:
        cells += [f"{row['cc_min']:.3f}", f"{row['cc_mean']:.3f}", f"{row['error_mean_ms']:.1f}"]
        cells.append(f"{row['error_worst_ms']:.1f}")
    else:
        cells += ["(finest)", "", "", ""]
    return "| " + " | ".join(cells) + " |"


def outside_scars(row: dict) -> np.ndarray:
    """(S,) the sites of ``row`` paced outside scars: less than
    :data:`~simgen.solver.stimulus.IN_SCAR` of their stimulus patch in a scar."""
    return np.asarray(row["site_scar_share"]) < IN_SCAR


def summary(rows: list[dict], resolutions: list[int]) -> tuple[list[str], dict[str, int | None]]:
    """Per resolution the worst figures over every heart and tissue, over every site and over the sites paced
    outside scars; and for each the converged resolution (or None)."""
    lines = [
        "| target nodes | sites | capture flips | smallest CC | largest mean activation error (ms) | worst site (ms) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    converged: dict[str, int | None] = {}
    for which, pick in (("every site", lambda r: None), ("paced outside scars", outside_scars)):
        ok = {}
        for nodes in resolutions[:-1]:
            here = [figures(r, pick(r)) for r in rows if r["target"] == nodes]
            flips = sum(f["flips"] for f in here)
            cc = np.nanmin([f["cc_min"] for f in here])
            error = np.nanmax([f["error_mean_ms"] for f in here])
            worst = np.nanmax([f["error_worst_ms"] for f in here])
            ok[nodes] = flips == 0 and cc >= GOAL_CC and error <= GOAL_ERROR_MS
            lines.append(f"| {nodes} | {which} | {flips} | {cc:.3f} | {error:.1f} | {worst:.1f} |")
        converged[which] = None
        for nodes in reversed(resolutions[:-1]):
            if not ok[nodes]:
                break
            converged[which] = nodes
    return lines, converged


def verdict(converged: dict[str, int | None]) -> str:
    """The converged resolution (:data:`GOAL_CC`, :data:`GOAL_ERROR_MS`, no flip), for every site and for sites
    paced outside scars."""
    parts = [f"{which} {f'from {n} nodes' if n else 'at no resolution here'}" for which, n in converged.items()]
    return (
        f"Converged (no capture flip, CC >= {GOAL_CC}, mean activation error <= {GOAL_ERROR_MS:g} ms): "
        + "; ".join(parts)
        + "."
    )


def pivot(rows: list[dict], resolutions: list[int]) -> list[str]:
    """One line per heart and tissue setting, one column per resolution but the finest: smallest CC; mean /
    worst-site activation error; flips; and the sites paced in a scar."""
    coarse = resolutions[:-1]
    lines = ["| heart | tissue | in scar | " + " | ".join(f"{n // 1000}k nodes" for n in coarse) + " |"]
    lines.append("|---|---|---:|" + "---|" * len(coarse))
    cells: dict[tuple[str, str, int], dict[int, str]] = {}
    for r in rows:
        if r["target"] in coarse:
            flips = f", {r['flips']} flip{'s' * (r['flips'] > 1)}" if r["flips"] else ""
            text = f"{r['cc_min']:.3f}; {r['error_mean_ms']:.1f} / {r['error_worst_ms']:.1f} ms{flips}"
            key = (r["heart"], r["tissue"], int((~outside_scars(r)).sum()))
            cells.setdefault(key, {})[r["target"]] = text
    for (heart, tissue, in_scar), by_nodes in cells.items():
        lines.append(f"| {heart} | {tissue} | {in_scar} | " + " | ".join(by_nodes.get(n, "") for n in coarse) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hearts", nargs="+", default=list(HEARTS), help="mesh sources (lv, biv, real:NAME)")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 2000, 5000, 10_000, 20_000])
    parser.add_argument("--tissue", nargs="+", default=list(TISSUES), help="default tissue setting names")
    parser.add_argument("--sites", type=int, default=6, help="pacing positions per heart")
    parser.add_argument("--radius", type=float, default=None, help="stimulus radius in mm (default: the solver's)")
    parser.add_argument("--legacy", action="store_true", help="edge-path patches of 1.5 mean edges, as old stores")
    parser.add_argument("--scar-border", choices=SCAR_BORDERS, default=SCAR_BORDERS[0], help="scars on the nodes")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path("report/bench/convergence-meshes"))
    add_out_argument(parser, "convergence")
    add_publish_argument(parser, "convergence")
    args = parser.parse_args()
    check_publish(args.publish)
    args.nodes = sorted(args.nodes)
    header = (
        "| heart | tissue | nodes | mean edge (mm) | stimulus radius (mm) | capture | in scar | flips | CC min "
        "| CC mean | activation error mean (ms) | worst site (ms) |"
    )
    print(f"{machine_line()}; {args.sites} pacing positions per heart, compared with {args.nodes[-1]} nodes")
    print(header + "\n|" + "---|" * 12)
    start = time.perf_counter()
    rows = [row for heart in args.hearts for row in heart_rows(heart, args)]
    lines, converged = summary(rows, args.nodes)
    text = "\n".join(
        [
            f"Machine: {machine_line()}. {len(args.hearts)} hearts x {len(args.tissue)} tissue settings x "
            f"{args.sites} pacing positions, each resolution against {args.nodes[-1]} nodes, scars placed by the "
            f"{args.scar_border!r} rule; "
            f"{time.perf_counter() - start:.0f} s.",
            "",
            header,
            "|" + "---|" * 12,
            *map(_row_line, rows),
            "",
            *lines,
            "",
            verdict(converged),
        ]
    )
    print("\n" + "\n".join(lines) + f"\n\n{verdict(converged)}")
    write_out(args.out, "convergence", text + "\n", {"machine": machine(), "rows": rows, "converged": converged})
    published = [
        f"Scars placed by the {args.scar_border!r} rule; {args.sites} pacing positions per heart; "
        f"{time.perf_counter() - start:.0f} s.",
        "",
        *pivot(rows, args.nodes),
        "",
        *lines,
        "",
        verdict(converged),
    ]
    publish_out(args.publish, "convergence", "\n".join(published))


if __name__ == "__main__":
    main()
