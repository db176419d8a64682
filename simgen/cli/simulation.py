"""``simgen simulate`` and ``simgen demo``: one mesh and tissue simulated into files, the demo sweep."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from shared.cli import MAX_SEED, SiteRegionOpt, SiteToleranceOpt, SiteXyzOpt, finite, parse_ids, print_markdown
from shared.errors import InputError
from shared.sites import SITE_TOLERANCE
from simgen.cli.options import (
    TISSUE_HELP,
    FibresOpt,
    FillerOpt,
    HeartOpt,
    HelixEndoOpt,
    HelixEpiOpt,
    KindOpt,
    MeshOpt,
    NodesOpt,
    ThreadsOpt,
    UnitsOpt,
    app,
    console,
    fail_input,
    mesh_options,
)
from simgen.solver.cells import CELL_MODELS, APParams
from simgen.solver.integrators import AUTO, integrator_help


@app.command()
def simulate(
    out: Annotated[Path, typer.Argument(help="Output folder (NPZ + activation-map PNG).")],
    source: MeshOpt = "lv",
    nodes: NodesOpt = None,
    kind: KindOpt = None,
    heart: HeartOpt = True,
    units: UnitsOpt = None,
    fibres: FibresOpt = False,
    helix_endo: HelixEndoOpt = None,
    helix_epi: HelixEpiOpt = None,
    filler: FillerOpt = None,
    anisotropy: Annotated[
        float | None,
        typer.Option(
            min=1.0,
            callback=finite,
            help="Conduction along the mesh's fibres over across them, D_l / D_t (about 4-7 in ventricles); "
            "the diffusivity is the along-fibre one. Unset: isotropic.",
        ),
    ] = None,
    sheet_anisotropy: Annotated[
        float | None,
        typer.Option(
            min=1.0,
            callback=finite,
            help="Conduction along the mesh's sheets over normal to them, D_s / D_n (orthotropic tissue; the "
            "rule-based fibres of --fibres come with sheets). Unset: transversely isotropic about the fibres.",
        ),
    ] = None,
    tissue: Annotated[str, typer.Option(help=TISSUE_HELP)] = "healthy",
    sites: Annotated[
        str | None, typer.Option(help="Comma-separated stimulation node ids of the mesh (default 0 without others).")
    ] = None,
    site_xyz: SiteXyzOpt = None,
    site_region: SiteRegionOpt = None,
    site_tolerance: SiteToleranceOpt = SITE_TOLERANCE,
    threads: ThreadsOpt = 2,
    dt: Annotated[float | None, typer.Option(callback=finite, help="Time step; automatic when omitted.")] = None,
    integrator: Annotated[str, typer.Option(help=integrator_help())] = AUTO,
    cell: Annotated[
        str,
        typer.Option(
            "--cell-model",
            help="Cell model: "
            + ", ".join(f"'{name}'" for name in CELL_MODELS)
            + " (published parameters; a spec's [solver.model] table sets others).",
        ),
    ] = APParams.name,
    backend: Annotated[
        str, typer.Option(help="Solver: 'numba' (CPU), 'torch' (any torch device) or 'auto' (torch on a GPU if any).")
    ] = "numba",
    device: Annotated[
        str | None, typer.Option(help="Torch device of the torch backend: cpu, cuda, cuda:N (default: cuda if any).")
    ] = None,
    observe: Annotated[
        str | None,
        typer.Option(
            help="Also write observations.npz, the recordings `learner personalize --observations` reads: u on this "
            "node set (surface, epicardium, endocardium, electrodes: the 247-electrode sock, or all); or 'ecg': "
            "ecg.npz and ecg.png, the 12-lead pseudo-ECG of each site (mV against ms), and observations.npz with "
            "the ECGs as recordings."
        ),
    ] = None,
    electrodes: Annotated[
        Path | None,
        typer.Option(
            help="With --observe ecg: a text file of 'name, x, y, z' lines (mm, the mesh's coordinates) instead of "
            "the standard placement; the 12 leads need RA, LA, LL and V1-V6, other sets give potentials only.",
        ),
    ] = None,
    record: Annotated[
        str,
        typer.Option(
            help="What observations.npz records: 'potential' (obs_mv, mV, at times_ms) or 'activation' "
            "(activation_ms: each observed node's activation time in ms, inf where it fires no action potential)."
        ),
    ] = "potential",
    noise: Annotated[
        float,
        typer.Option(
            min=0,
            callback=finite,
            help="Gaussian noise std added to the recordings: mV (potential, ECG) or ms (activation).",
        ),
    ] = 0.0,
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="Seed of the observation noise.")] = 0,
    vtk: Annotated[
        Path | None,
        typer.Option(help="Folder for a ParaView time series per site (site-<node>.pvd: V_mV, u, activation_ms)."),
    ] = None,
) -> None:
    """Simulate stimulation sites (node ids, points or regions) on one mesh + tissue and save the potential (mV),
    activation times (ms) and a figure; a mesh file without --nodes is used as it is, results on its own node ids
    (the Python function: :func:`simgen.outputs.simulate_files`)."""
    from shared.sites import parse_points, parse_regions
    from simgen.outputs import simulate_files

    try:
        helix = mesh_options(fibres, helix_endo, helix_epi, filler, nodes)
        run = simulate_files(
            out,
            source,
            nodes,
            kind,
            heart,
            units,
            fibres,
            helix,
            filler,
            anisotropy,
            sheet_anisotropy,
            tissue,
            None if sites is None else parse_ids(sites, "--sites"),
            None if site_xyz is None else parse_points(site_xyz),
            None if site_region is None else parse_regions(site_region),
            site_tolerance,
            threads,
            dt,
            integrator,
            cell,
            backend,
            device,
            observe,
            electrodes,
            record,
            noise,
            seed,
            vtk,
        )
    except (InputError, ValueError) as exc:
        fail_input(exc)
    except OSError as exc:
        fail_input(exc, out)
    console.print(run.summary())
    for note in run.notes:
        console.print(f"[yellow]{escape(note)}[/yellow]", soft_wrap=True)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Report folder.")] = Path("report/demo"),
    nodes: NodesOpt = 2000,
    sites_per_setting: Annotated[
        int, typer.Option(min=1, max=10_000, help="Stimulation sites per tissue setting.")
    ] = 4,
    threads: ThreadsOpt = 2,
) -> None:
    """Run the demo sweep (LV + BiV, four tissue settings) and write figures and a summary."""
    from simgen.demo import run_demo

    try:
        rows = run_demo(out, n_nodes=nodes, n_sites=sites_per_setting, threads=threads)
    except (InputError, OSError) as exc:
        fail_input(exc, out)
    print_markdown(console, (out / "summary.md").read_text())
    console.print(f"{sum(len(r.sites) for r in rows)} simulations, figures in {out}/")
