"""``simgen mesh`` and ``simgen tissues``: a mesh file written, tissue settings listed in physical terms."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from shared.errors import InputError
from simgen.cli.options import (
    FibresOpt,
    FillerOpt,
    HeartOpt,
    HelixEndoOpt,
    HelixEpiOpt,
    KindOpt,
    MeshOpt,
    NodesOpt,
    UnitsOpt,
    app,
    console,
    fail_input,
    mesh_options,
)
from simgen.meshes.catalog import get_mesh
from simgen.meshes.quality import mesh_quality
from simgen.solver.simulate import SolverConfig
from simgen.tissue import default_settings


@app.command()
def mesh(
    out: Annotated[Path, typer.Argument(help="Output mesh file (.vtu, .vtk, .msh, ...).")],
    source: MeshOpt = "lv",
    nodes: NodesOpt = None,
    kind: KindOpt = None,
    heart: HeartOpt = True,
    units: UnitsOpt = None,
    fibres: FibresOpt = False,
    helix_endo: HelixEndoOpt = None,
    helix_epi: HelixEpiOpt = None,
    filler: FillerOpt = None,
) -> None:
    """Generate (or load and validate) a mesh and write it to OUT, with its node sets and, for a heart, its
    region labels (AHA segments, RV free wall) as point data: what sites by region need. With --fibres also
    its fibres (point data fibre), the ventricular coordinates they come from (transmural, apicobasal,
    rv_share) and a picture of them (OUT with suffix .fibres.png)."""
    from simgen.outputs import write_mesh

    try:
        helix = mesh_options(fibres, helix_endo, helix_epi, filler, nodes)
        m = write_mesh(out, source, nodes, kind, heart, units, fibres, helix, filler)
    except (InputError, OSError) as exc:
        fail_input(exc, out)
    table = Table(title=f"{m.name} -> {out}")
    for key, value in [
        ("nodes", m.n_nodes),
        ("cells", f"{m.n_cells} {m.cell_type}"),
        ("mean edge (mm)", f"{m.mean_edge_length():.2f}"),
        *mesh_quality(m).rows(),
        *[(f"node set {k}", len(v)) for k, v in m.node_sets.items()],
    ]:
        table.add_row(key, str(value))
    console.print(table)


@app.command()
def tissues(
    spec: Annotated[
        Path | None,
        typer.Option(help="A build spec: list its settings, named and drawn ([tissue_prior]); unset: the 16 defaults."),
    ] = None,
    png: Annotated[Path | None, typer.Option(help="Draw the first --show settings on a mesh into this PNG.")] = None,
    show: Annotated[int, typer.Option(min=1, max=12, help="How many settings the PNG draws.")] = 4,
    mesh: Annotated[
        str | None,
        typer.Option("--mesh", help="The PNG's mesh: 'lv', 'biv', a file (default: the spec's first, or lv)."),
    ] = None,
) -> None:
    """List tissue settings in physical terms: CV (m/s, along / across fibres) and APD90 (ms) measured on a strip,
    scars and fibrosis; with --png, a picture of a few on a mesh."""
    from simgen.store.manifest import entry_mesh
    from simgen.store.spec import load_spec
    from simgen.tissue.report import TISSUE_COLUMNS, plot_tissue_draws, tissue_rows

    settings, solver, first = default_settings(), SolverConfig(), None
    try:
        if spec is not None:
            build = load_spec(spec)
            settings, solver, first = build.settings(), build.solver, build.meshes[0]
        table = Table()
        for column in TISSUE_COLUMNS:
            table.add_column(column, no_wrap=column == "name")
        for row in tissue_rows(settings, solver):
            table.add_row(*(escape(row[c]) for c in TISSUE_COLUMNS))
    except (InputError, OSError) as exc:
        fail_input(exc, spec)
    console.print(table)
    if png is None:
        return
    try:
        on = get_mesh(mesh or "lv", 2000, "tetra") if mesh is not None or first is None else entry_mesh(first)
        png.parent.mkdir(parents=True, exist_ok=True)
        plot_tissue_draws(on, settings[:show], png)
    except (InputError, OSError) as exc:
        fail_input(exc, png)
    console.print(f"wrote {png}")
