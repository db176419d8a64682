"""Conduction-velocity verification table, published in docs/method.md ("Verification of the solver").

Planar front speed against ``sqrt(2kD)(1/2 - a)`` on strips (triangles) and
slabs (tetrahedra) under refinement and at the default resolution of the default
LV mesh (D = 100 mm^2/tu, h = its mean edge); APD50. Whole hearts under mesh
refinement: bench/convergence.py.

    python -m bench.conduction [--out DIR]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.common import add_out_argument, write_out
from simgen.meshes.ellipsoid import lv_ellipsoid
from simgen.meshes.slab import slab, strip
from simgen.solver.simulate import SolverConfig
from simgen.solver.verification import action_potential_duration, speed_error


def planar_rows() -> list[dict]:
    rows = []
    default_h = lv_ellipsoid(2000, "tetra").mean_edge_length()
    D = SolverConfig().diffusivity
    cases = [("strip", h, 1.0, lambda h=h: strip(30.0, 1.0, h)) for h in (0.5, 0.25, 0.125)]
    cases += [("slab", h, 1.0, lambda h=h: slab(20.0, 1.0, 1.0, h)) for h in (0.5, 0.25)]
    cases += [("slab (default LV resolution)", default_h, D, lambda: slab(250.0, 12.0, 12.0, default_h))]
    for name, h, diff, make in cases:
        for a in (0.15, 0.3):
            start = time.perf_counter()
            err = speed_error(make(), a, diffusivity=diff)
            rows.append(
                {
                    "mesh": name,
                    "h": round(h, 3),
                    "D": diff,
                    "h/sqrt(D)": round(h / np.sqrt(diff), 3),
                    "a": a,
                    "speed error %": round(100 * err, 2),
                    "seconds": round(time.perf_counter() - start, 2),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_out_argument(parser, "conduction")
    args = parser.parse_args()
    rows = planar_rows()
    apd = action_potential_duration(strip(10.0, 0.5, 0.25), x=5.0)
    lines = ["| mesh | h | D | h/sqrt(D) | a | speed error vs sqrt(2kD)(1/2-a) |", "|---|---|---|---|---|---|"]
    lines += [
        f"| {r['mesh']} | {r['h']} | {r['D']:g} | {r['h/sqrt(D)']} | {r['a']} | {r['speed error %']:+.1f} % |"
        for r in rows
    ]
    lines += ["", f"APD50 at a = 0.15: {apd:.1f} time units ({apd * 12.9:.0f} ms); expected about 23."]
    table = "\n".join(lines)
    print(table)
    write_out(args.out, "conduction", table + "\n", {"planar": rows, "apd50": apd}, indent=2)


if __name__ == "__main__":
    main()
