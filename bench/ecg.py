"""Benchmark: the pseudo-ECG's convergence with the mesh and its cost against the simulation.

The procedural LV at about ``--nodes`` nodes each (default 1,000, 2,000, 5,000, 10,000), three pacing
sites at the nodes nearest the same points, the standard electrodes (:mod:`shared.ecg`). Per mesh:
the correlation of each lead of each site with the finest mesh's (minimum and mean over the 36; a lead
that stays near zero correlates poorly whatever its size), the RMS of the difference from the finest over
the finest's RMS, the
largest difference of the QRS end (every lead within 5% of its peak after it) from the latest activation
time, the time to assemble the ECG operator, to compute one simulation's 12 leads, and to simulate one
site (one thread, the default integrator).

Run::

    .venv/bin/python -m bench.ecg --out report/bench

``--publish`` writes the table into the block ``ecg`` of docs/results.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.common import add_out_argument, add_publish_argument, check_publish, machine, publish_out, write_out
from shared.ecg import PseudoECG, leads, standard_electrodes
from shared.units import MS_PER_TIME_UNIT
from simgen.meshes.catalog import get_mesh
from simgen.solver.simulate import Simulator


def qrs_end(ecg: np.ndarray, times: np.ndarray, latest: float) -> float:
    """The last time before the T wave at which some lead is above 5% of the QRS's peak."""
    magnitude = np.abs(ecg).max(axis=0)
    early = times < latest + 100.0
    return float(times[early][np.flatnonzero(magnitude[early] > 0.05 * magnitude[early].max()).max()])


def measure(nodes: list[int]) -> list[dict]:
    rows, points, finest = [], None, None
    for n in sorted(nodes, reverse=True):  # the finest first: it is the reference
        mesh = get_mesh("lv", n)
        points = mesh.points[[0, 300, 700]] if points is None else points
        sites = np.array([int(np.argmin(np.linalg.norm(mesh.points - p, axis=1))) for p in points])
        start = time.perf_counter()
        result = Simulator(mesh).run(sites, threads=1)
        simulated = time.perf_counter()
        electrodes = standard_electrodes(mesh)
        operator = PseudoECG.assemble(mesh, electrodes)
        assembled = time.perf_counter()
        ecg = leads(operator.potentials(result.u), electrodes)
        done = time.perf_counter()
        finest = ecg if finest is None else finest
        cc = [np.corrcoef(a, b)[0, 1] for sa, sb in zip(ecg, finest) for a, b in zip(sa, sb)]
        times, latest = result.times * MS_PER_TIME_UNIT, np.nanmax(result.activation, axis=1) * MS_PER_TIME_UNIT
        rows.append(
            {
                "nodes": mesh.n_nodes,
                "cc_min": float(np.min(cc)),
                "cc_mean": float(np.mean(cc)),
                "rms": float(np.sqrt(np.mean((ecg - finest) ** 2) / np.mean(finest**2))),
                "qrs_error_ms": max(abs(qrs_end(e, times, t) - t) for e, t in zip(ecg, latest)),
                "frame_ms": float(times[1] - times[0]),
                "assemble_s": assembled - simulated,
                "ecg_ms": 1e3 * (done - assembled) / len(sites),
                "simulate_s": (simulated - start) / len(sites),
            }
        )
    return rows[::-1]


def table(rows: list[dict]) -> str:
    finest = rows[-1]["nodes"]
    lines = [
        f"Three sites on the procedural LV; CC per lead and site against {finest:,} nodes; frames every "
        f"{rows[0]['frame_ms']:.1f} ms.",
        "",
        "| nodes | CC min | CC mean | relative RMS difference | QRS end - latest activation (ms, max) | operator (s) "
        "| ECG per simulation (ms) | simulation per site (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['nodes']:,} | {r['cc_min']:.3f} | {r['cc_mean']:.3f} | {r['rms']:.3f} | {r['qrs_error_ms']:.1f} | "
            f"{r['assemble_s']:.3f} | {r['ecg_ms']:.1f} | {r['simulate_s']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[1000, 2000, 5000, 10000])
    add_out_argument(parser, "ecg")
    add_publish_argument(parser, "ecg")
    args = parser.parse_args(argv)
    check_publish(args.publish)
    start = time.perf_counter()
    rows = measure(args.nodes)
    markdown = table(rows)
    print(markdown)
    print(f"({time.perf_counter() - start:.0f} s)")
    write_out(args.out, "ecg", markdown, {"machine": machine(), "rows": rows})
    publish_out(args.publish, "ecg", markdown)


if __name__ == "__main__":
    main()
