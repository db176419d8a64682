"""Figure of sampled anatomies: a row of random LVs and a row of random BiVs.

Draws ``--count`` anatomies per family with :func:`simgen.meshes.anatomy.sample_anatomies`
(seed ``--seed``), renders their surfaces on one scale into ``--figure`` and
prints a Markdown table of their main parameters and the time step the solver
would choose on each, relative to the default mesh of the family. The figure
is published as docs/anatomies.png ([docs/anatomies.md](../docs/anatomies.md)).
``--out DIR`` also writes the table and every anatomy's complete parameters
(``anatomies.md``, ``anatomies.json``).

Run::

    .venv/bin/python -m bench.anatomies                       # about 20 s
    .venv/bin/python -m bench.anatomies --figure out.png --count 4 --nodes 800 [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.common import add_out_argument, write_out
from shared.mesh import Mesh
from simgen.meshes.anatomy import Anatomy, sample_anatomies
from simgen.meshes.catalog import get_mesh
from simgen.plot import plot_surfaces
from simgen.solver.simulate import SolverConfig, assemble, healthy_fields

FAMILIES = ("lv", "biv")
COLUMNS = ("length", "endo_radius", "wall_thickness", "eccentricity_index", "apex_offset", "bump_amplitude")


def time_step(mesh: Mesh) -> float:
    """The automatic time step of the default solver settings on healthy tissue."""
    return assemble(mesh, healthy_fields(mesh.n_nodes), SolverConfig()).dt


def table(samples: list[Anatomy], default_dt: dict[str, float]) -> str:
    """Markdown: one row per anatomy, its main parameters and its dt / the default mesh's dt."""
    lines = ["| mesh | " + " | ".join(COLUMNS) + " | dt / default dt |", "|---" * (len(COLUMNS) + 2) + "|"]
    for a in samples:
        family = a.mesh.name.split("-")[0]
        values = " | ".join(f"{a.params[c]:.2f}" for c in COLUMNS)
        lines.append(f"| {a.mesh.name} | {values} | {time_step(a.mesh) / default_dt[family]:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "anatomies.png")
    parser.add_argument("--count", type=int, default=6, help="anatomies per family")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--nodes", type=int, default=1500, help="nodes per mesh")
    add_out_argument(parser, "anatomies")
    args = parser.parse_args()
    samples = [a for family in FAMILIES for a in sample_anatomies(family, args.count, args.seed, nodes=args.nodes)]
    titles = [
        f"{a.mesh.name}: {a.params['length']:.0f} mm, wall {a.params['wall_thickness']:.1f} mm\n"
        f"EI {a.params['eccentricity_index']:.2f}, bumps {a.params['bump_amplitude']:.1f} mm"
        for a in samples
    ]
    plot_surfaces([a.mesh for a in samples], titles, args.figure, n_cols=args.count)
    default_dt = {family: time_step(get_mesh(family, args.nodes)) for family in FAMILIES}
    text = table(samples, default_dt)
    print(f"{text}\n\nfigure: {args.figure}")
    write_out(args.out, "anatomies", text + "\n", {a.mesh.name: a.params for a in samples}, indent=2)


if __name__ == "__main__":
    main()
