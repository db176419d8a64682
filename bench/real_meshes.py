"""The shipped real meshes through the whole pipeline: one PNG each in docs/, and a table.

For each ``real:<name>`` mesh (:mod:`simgen.meshes.shipped`): load it, resample it to
``--nodes`` nodes of ``--kind`` cells, detect its node sets and long axis, label its
AHA segments and simulate one activation from the epicardial node nearest the apex, then
draw node sets, segments and activation map into ``docs/real-<name>.png``
([docs/anatomies.md](../docs/anatomies.md)). Prints a Markdown table: nodes before and
after, symmetric Hausdorff distance between the file's surface and the resampled one,
node-set sizes, seconds to load and resample, the solver's time step; ``--publish`` writes it
into the block ``real_meshes`` of docs/results.md.

Run::

    .venv/bin/python -m bench.real_meshes                  # about 1-2 min
    .venv/bin/python -m bench.real_meshes --nodes 1000 --kind triangle --out /tmp/real
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench.common import add_publish_argument, check_publish, machine_line, publish_out
from simgen.meshes import get_mesh
from simgen.meshes.io import load_mesh
from simgen.meshes.resample import hausdorff_distance
from simgen.meshes.shipped import REAL_MESHES, REAL_PREFIX, unpacked
from simgen.plot import plot_mesh_overview
from simgen.solver import MS_PER_TIME_UNIT, Simulator
from simgen.solver.simulate import healthy_fields
from simgen.tissue import aha_segments

SETS = ("epicardium", "lv_endocardium", "rv_endocardium", "endocardium", "base")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=2000)
    parser.add_argument("--kind", choices=("tetra", "triangle"), default="tetra")
    parser.add_argument("--out", type=Path, default=Path("docs"), help="folder for the real-<name>.png figures")
    add_publish_argument(parser, "real_meshes")
    args = parser.parse_args()
    check_publish(args.publish)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"Machine: {machine_line()}\n")
    lines = [
        f"| mesh | nodes in file | nodes ({args.kind}) | Hausdorff (mm) | "
        + " | ".join(SETS)
        + " | load + resample (s) | dt |",
        "|---" * (len(SETS) + 6) + "|",
    ]
    print("\n".join(lines))
    for name in REAL_MESHES:
        source = REAL_PREFIX + name
        start = time.perf_counter()
        mesh = get_mesh(source, args.nodes, args.kind)
        seconds = time.perf_counter() - start
        with unpacked(source) as path:
            original = load_mesh(path, units="mm")  # the file as it is
        distance = hausdorff_distance(original, mesh)
        epicardium = mesh.nodes("epicardium")
        site = int(epicardium[np.argmin(np.linalg.norm(mesh.points[epicardium] - mesh.axis.apex, axis=1))])
        simulator = Simulator(mesh, healthy_fields(mesh.n_nodes))
        result = simulator.run(np.array([site]), threads=2)
        plot_mesh_overview(
            mesh,
            aha_segments(mesh),
            result.activation[0] * MS_PER_TIME_UNIT,
            site,
            args.out / f"real-{name}.png",
            f"{source}: {mesh.n_nodes} nodes ({args.kind}), stimulus at the apex",
        )
        sizes = " | ".join(str(len(mesh.node_sets.get(s, []))) for s in SETS)
        lines.append(
            f"| `{source}` | {original.n_nodes} | {mesh.n_nodes} | {distance:.2f} | {sizes} | {seconds:.1f} | "
            f"{simulator.dt:.3g} |"
        )
        print(lines[-1], flush=True)
    publish_out(args.publish, "real_meshes", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
