"""The ``simgen`` command line: thin wrappers around library functions."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from shared.cli import (
    MAX_SEED,
    SiteRegionOpt,
    SiteToleranceOpt,
    SiteXyzOpt,
    fail,
    finite,
    needs,
    parse_ids,
    print_markdown,
)
from shared.errors import InputError
from shared.sites import SITE_TOLERANCE
from simgen.meshes.catalog import get_mesh
from simgen.meshes.fibres import HELIX_ENDO, HELIX_EPI
from simgen.meshes.quality import mesh_quality
from simgen.solver.cells import CELL_MODELS, APParams
from simgen.solver.integrators import AUTO, integrator_help
from simgen.solver.simulate import SolverConfig
from simgen.tissue import default_settings, named_setting

if TYPE_CHECKING:
    from simgen.store.estimate import BuildEstimate

app = typer.Typer(
    help="simgen: Aliev-Panfilov cardiac simulations on heart meshes, swept into datasets.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()

MeshOpt = Annotated[str, typer.Option("--mesh", help="'lv', 'biv' or a mesh file (any meshio format).")]
NodesOpt = Annotated[
    int | None,
    typer.Option(
        "--nodes",
        min=1,
        help="Target node count: a procedural mesh's (default 2000), or a mesh file's resampled to it; without it "
        "a mesh file (and a shipped real mesh) is used as it is, its node ids kept.",
    ),
]
KindOpt = Annotated[
    str | None,
    typer.Option("--kind", help="'tetra' (volume) or 'triangle' (surface); default: a file's own, tetra otherwise."),
]
FillerOpt = Annotated[
    str | None,
    typer.Option(
        help="How a surface is filled with tetrahedra (--kind tetra with --nodes): 'ftetwild' (any surface, one "
        "that crosses itself or is merged from parts included), 'tetgen' (keeps the surface; needs the tetra "
        "extra), or 'auto' (default: tetgen where installed and the surface is clean, else ftetwild).",
    ),
]
HeartOpt = Annotated[
    bool,
    typer.Option(
        "--heart/--no-heart",
        help="A mesh file must be a heart (its node sets are detected); --no-heart accepts one that is not (a slab).",
    ),
]
UnitsOpt = Annotated[
    str | None,
    typer.Option(
        "--units",
        help="Length unit of a mesh file's coordinates: mm, cm or m (default: the file's own, else inferred from "
        "a heart's size; mm for --no-heart).",
    ),
]
FibresOpt = Annotated[
    bool,
    typer.Option(
        "--fibres/--no-fibres",
        help="Rule-based fibres (LDRB: helix +60 to -60 degrees through the wall; LV and BiV volume meshes) "
        "where the mesh carries none (a file's own point data 'fibre' is used as it is).",
    ),
]
HelixEndoOpt = Annotated[
    float | None,
    typer.Option(
        min=-90, max=90, callback=finite, help=f"With --fibres: helix angle at the endocardium (deg; {HELIX_ENDO:g})."
    ),
]
HelixEpiOpt = Annotated[
    float | None,
    typer.Option(
        min=-90, max=90, callback=finite, help=f"With --fibres: helix angle at the epicardium (deg; {HELIX_EPI:g})."
    ),
]
TISSUE_HELP = (
    "A setting name (`simgen tissues`) or a TOML file: name; healthy = {a, D}; apd_scale; fibrosis; scars, each "
    "with region ('segments' + segments 1-17, 'sphere' + node or centre and radius in mm, or 'wall' + height, "
    "angle, radius), border_width in mm, core and border {a, D} (docs/formats.md, examples/scar.toml)."
)
SchedulerOpt = Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler.")]
WorkersOpt = Annotated[int, typer.Option(min=1, max=1024, help="Local worker processes when no --scheduler is given.")]
ThreadsOpt = Annotated[int, typer.Option(min=1, max=1024, help="Solver threads.")]
GpusOpt = Annotated[
    int,
    typer.Option(
        min=0,
        max=1024,
        help="Run tasks on GPU workers with the spec's torch backend: locally one worker per GPU (replaces "
        "--workers); with --scheduler on its workers started with --resources GPU=1.",
    ),
]
# A string, not a Path: Path("s3://bucket/x.zarr") would collapse the "//" of a URL.
StoreArg = Annotated[str, typer.Argument(help="A simgen Zarr store: a folder or an fsspec URL (s3://bucket/x.zarr).")]


def _fail(exc: Exception, path: str | Path | None = None) -> NoReturn:
    """Report bad input on one line and exit with code 2 (:func:`shared.cli.fail`)."""
    fail(console, exc, path)


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
        helix = _mesh_options(fibres, helix_endo, helix_epi, filler, nodes)
        m = write_mesh(out, source, nodes, kind, heart, units, fibres, helix, filler)
    except (InputError, OSError) as exc:
        _fail(exc, out)
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
        _fail(exc, spec)
    console.print(table)
    if png is None:
        return
    try:
        on = get_mesh(mesh or "lv", 2000, "tetra") if mesh is not None or first is None else entry_mesh(first)
        png.parent.mkdir(parents=True, exist_ok=True)
        plot_tissue_draws(on, settings[:show], png)
    except (InputError, OSError) as exc:
        _fail(exc, png)
    console.print(f"wrote {png}")


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
        helix = _mesh_options(fibres, helix_endo, helix_epi, filler, nodes)
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
        _fail(exc)
    except OSError as exc:
        _fail(exc, out)
    console.print(run.summary())
    for note in run.notes:
        console.print(f"[yellow]{escape(note)}[/yellow]", soft_wrap=True)


def _mesh_options(
    fibres: bool, helix_endo: float | None, helix_epi: float | None, filler: str | None, nodes: int | None
) -> tuple[float, float]:
    """The helix angles of the rule-based fibres; options that would have no effect are refused by name."""
    needs("--helix-endo", helix_endo is not None, "--fibres", fibres)
    needs("--helix-epi", helix_epi is not None, "--fibres", fibres)
    needs("--filler", filler is not None, "--nodes", nodes is not None)
    return (HELIX_ENDO if helix_endo is None else helix_endo, HELIX_EPI if helix_epi is None else helix_epi)


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
        _fail(exc, out)
    print_markdown(console, (out / "summary.md").read_text())
    console.print(f"{sum(len(r.sites) for r in rows)} simulations, figures in {out}/")


@app.command()
def build(
    spec: Annotated[Path, typer.Argument(help="Build spec (TOML), e.g. specs/demo.toml.")],
    store: Annotated[str, typer.Option(help="Output Zarr store: a folder or an fsspec URL (s3://bucket/name.zarr).")],
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
    force: Annotated[
        bool,
        typer.Option(
            help="Replace a store that cannot be resumed: built from another spec or an older schema version, "
            "or damaged (`simgen repair` keeps its finished chunks)."
        ),
    ] = False,
    retries: Annotated[int, typer.Option(min=0, max=100, help="Retries per failing task.")] = 2,
    dry_run: Annotated[
        bool,
        typer.Option(
            help="Print the plan (disk, memory, time) and run every check of the build (spec, meshes, tissue, "
            "resources, the store's lock, spec and structure); write nothing, exit 2 where the build would refuse."
        ),
    ] = False,
    gpus: GpusOpt = 0,
) -> None:
    """Build (or resume) the dataset of SPEC into STORE on a Dask cluster, after printing its plan.

    The build is refused when a task needs more memory than a worker may use or
    the store more disk space than is free. With --gpus the spec must set
    [solver] backend = "torch" or "auto" (docs/solver-backends.md).
    """
    from simgen.store import load_spec
    from simgen.store.runner import build as run_build
    from simgen.store.runner import dry_run as run_dry

    if dry_run:
        try:
            state = run_dry(load_spec(spec), store, scheduler, workers, force, _show_plan, gpus)
        except (InputError, OSError) as exc:
            _fail(exc, store)
        console.print(f"dry run: nothing written; the build would {_WOULD[state]}")
        return
    _run_with_progress(
        store,
        lambda on_start, on_done: run_build(
            load_spec(spec), store, scheduler, workers, force, retries, on_start, on_done, _show_plan, gpus
        ),
    )


#: What a build does with its store, by :func:`simgen.store.runner.store_state`.
_WOULD = {"new": "lay out a new store", "resume": "resume the store", "replace": "replace the store (--force)"}


def _show_plan(estimate: BuildEstimate) -> None:
    """Print a build's :class:`~simgen.store.estimate.BuildEstimate`."""
    console.print("[bold]plan[/bold]\n  " + escape("\n  ".join(estimate.lines())), soft_wrap=True)


class _LogLines:
    """A progress bar's interface for a log: a plain line at most every ``every_s`` seconds, and the last."""

    def __init__(self, every_s: float = 30.0) -> None:
        self.every_s, self.done, self.total, self.printed = every_s, 0, 0, -math.inf

    def add_task(self, description: str, total: int) -> int:
        self.total = total
        return 0

    def update(self, task: int, advance: int, description: str) -> None:
        self.done += advance
        if self.done == self.total or time.monotonic() - self.printed >= self.every_s:
            self.printed = time.monotonic()
            console.print(f"simulated {self.done}/{self.total} chunks ({description})", soft_wrap=True)

    def start(self) -> None:
        """Nothing to draw."""

    def stop(self) -> None:
        """Nothing to clear."""


def _progress_bar():
    """A rich progress bar on a terminal, plain periodic lines elsewhere."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if not console.is_terminal:
        return _LogLines()
    return Progress(
        TextColumn("[bold]simulating"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.description}"),
        console=console,
    )


def _run_with_progress(store: str, job, idle: str = "nothing to do") -> None:
    """Run ``job(on_start, on_done)`` behind a progress bar (plain lines in a log) and print what it did
    (``idle``: what to say when it computed no chunk)."""
    bar = _progress_bar()
    state: dict = {}

    def on_start(n: int, dashboard: str | None) -> None:
        console.print(f"Dask dashboard: {dashboard}")
        state["task"] = bar.add_task("", total=n)
        bar.start()

    def on_done(key: str) -> None:
        bar.update(state["task"], advance=1, description=key)

    try:
        report = job(on_start, on_done)
    except (InputError, ValueError, OSError) as exc:
        bar.stop()
        _fail(exc, store)
    bar.stop()
    if report.tasks_run == 0:
        console.print(f"{store}: {idle}, all {report.tasks_total} chunks done")
    else:
        console.print(
            f"{store}: {report.tasks_run}/{report.tasks_total} chunks, {report.simulations} simulations in "
            f"{report.seconds:.1f} s ({report.simulations / report.seconds:.1f} sims/s)"
        )


@app.command("add-subject")
def add_subject(
    store: StoreArg,
    mesh_file: Annotated[str, typer.Option("--mesh", help="Mesh file of the new subject, or 'lv' / 'biv'.")],
    mesh_id: Annotated[str, typer.Option("--id", help="Mesh id in the store; subjects are '<id>-<tissue>'.")],
    tissue: Annotated[list[str], typer.Option(help=f"{TISSUE_HELP} Repeat for several.")],
    nodes: NodesOpt = 2000,
    kind: KindOpt = "tetra",
    units: UnitsOpt = None,
    filler: FillerOpt = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
) -> None:
    """Add a subject (e.g. a new patient geometry) to STORE and simulate only it."""
    from simgen.store.edit import add_subject as run_add
    from simgen.store.spec import MeshEntry

    def job(on_start, on_done):
        specs = [named_setting(t) for t in tissue]
        return run_add(
            store,
            MeshEntry(mesh_id, mesh_file, nodes, kind, units=units, filler=filler),  # type: ignore[arg-type]
            specs,
            scheduler=scheduler,
            workers=workers,
            on_start=on_start,
            on_done=on_done,
        )

    _run_with_progress(store, job)


@app.command()
def regenerate(
    store: StoreArg,
    subjects: Annotated[str, typer.Option(help="Comma-separated subject ids (see `simgen status`).")],
    site_index: Annotated[
        str | None,
        typer.Option(help="Comma-separated site indices (`simgen sites` maps them to node ids); all when omitted."),
    ] = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
) -> None:
    """Recompute only the chunks of SUBJECTS (or of the given site indices) and rewrite them."""
    from simgen.store.edit import regenerate as run_regenerate

    def job(on_start, on_done):
        indices = None if site_index is None else parse_ids(site_index, "--site-index")
        return run_regenerate(
            store,
            [s.strip() for s in subjects.split(",") if s.strip()],
            indices,
            scheduler=scheduler,
            workers=workers,
            on_start=on_start,
            on_done=on_done,
        )

    _run_with_progress(store, job)


@app.command()
def repair(
    store: StoreArg,
    spec: Annotated[
        Path | None,
        typer.Option(
            help="The spec STORE was built from: needed when its root metadata or recorded spec is gone; "
            "when given, it must be STORE's (see --rescope)."
        ),
    ] = None,
    rescope: Annotated[
        bool,
        typer.Option(
            help="Make STORE the --spec's: subjects it does not imply are removed, new ones laid out and "
            "computed (same solver, output and sites only)."
        ),
    ] = False,
    remove_extra: Annotated[
        bool,
        typer.Option(
            help="Delete Zarr groups and arrays the recorded spec does not imply (else refused); files without "
            "Zarr metadata are a user's and never deleted."
        ),
    ] = False,
    dry_run: Annotated[bool, typer.Option(help="Print what the repair would change first; write nothing.")] = False,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
) -> None:
    """Restore a damaged STORE from its recorded spec, deleting or recomputing only what a check proved damaged.

    Prints its plan before it writes: root attributes, group and array metadata,
    mesh arrays, tissue fields and coordinates (made again from the spec), chunks
    whose data fail a check (computed again) and chunks whose data pass every
    check (flagged done); then finishes the build. Refused, with nothing changed,
    for a path that is not a store, a --spec that is not STORE's, members the
    spec does not imply (see --remove-extra) and arrays this simgen makes
    otherwise than the store holds them.
    """
    from simgen.store.repair import plan_repair, repair_store

    try:
        needs("--rescope", rescope, "--spec", spec is not None)
    except InputError as exc:
        _fail(exc)
    if dry_run:
        try:
            lines = plan_repair(store, spec, rescope, remove_extra).lines()
        except InputError as exc:
            _fail(exc)
        for line in lines or [f"{store}: nothing to repair"]:
            console.print(f"plan: {line}" if lines else line, soft_wrap=True)
        if lines:
            console.print("(damage these changes hide is found once they are made)")
        return
    reports = []

    def show(lines: list[str]) -> None:
        for line in lines:
            console.print(f"plan: {line}", soft_wrap=True)

    def job(on_start, on_done):
        reports.append(
            repair_store(
                store,
                spec,
                scheduler,
                workers,
                on_start=on_start,
                on_done=on_done,
                rescope=rescope,
                remove_extra=remove_extra,
                on_plan=show,
            )
        )
        return reports[0].build

    _run_with_progress(store, job, idle="no chunk to compute")
    for line in reports[0].lines():
        console.print(f"repaired: {line}", soft_wrap=True)
    if not reports[0].lines() and not reports[0].build.tasks_run:
        console.print(f"{store}: nothing was damaged")


@app.command()
def status(
    store: StoreArg,
    checksums: Annotated[
        bool, typer.Option(help="Also decode every done chunk as `simgen verify` does (reads the whole store).")
    ] = False,
) -> None:
    """Per-subject progress of a (possibly unfinished) build, and the damage a cheap check finds (exit 1 if any)."""
    from simgen.store.inspect import store_health

    try:
        health = store_health(store, checksums=checksums)
    except InputError as exc:
        _fail(exc)
    rows = health.rows
    table = Table("subject", "mesh", "chunks done", "sites", "no wave", "damaged", title=str(store))
    for r in rows:
        if r.missing:
            table.add_row(r.subject_id, r.mesh_id, f"0/{r.chunks}", str(r.sites), "", "group missing or damaged")
        else:
            damaged = f"{r.damaged} chunk(s)" if r.damaged else ""
            no_wave = "-" if r.no_wave is None else str(r.no_wave)
            table.add_row(r.subject_id, r.mesh_id, f"{r.chunks_done}/{r.chunks}", str(r.sites), no_wave, damaged)
    console.print(table)
    done = sum(r.chunks_done for r in rows)
    total = sum(r.chunks for r in rows)
    share = f"{done}/{total} chunks done ({100 * done / max(total, 1):.0f}%)"
    if health.problems:
        console.print(f"{share}; the store is damaged (below)")
    elif health.checksums:
        console.print(f"{share}; every chunk decoded: sound")
    else:
        console.print(f"{share}; structure sound, chunk data not decoded (`simgen status --checksums` decodes them)")
    counted = [r for r in rows if r.no_wave is not None]
    if counted:
        console.print(
            f"{sum(r.no_wave for r in counted)} of {sum(r.sites for r in counted)} simulations start no propagating "
            f"wave (a stimulus in a scar core; `no wave` per subject, '-': not recorded or chunks pending)"
        )
    if health.problems:
        for problem in health.problems[:20]:
            console.print(f"damaged: {escape(problem)}", soft_wrap=True)
        more = f" ({len(health.problems) - 20} more not shown)" if len(health.problems) > 20 else ""
        console.print(
            f"{len(health.problems)} problem(s){more}: run `simgen repair {store}` "
            f"(`simgen verify {store}` also decodes every chunk)",
            soft_wrap=True,
        )
        raise typer.Exit(code=1)


@app.command()
def sites(
    store: StoreArg, subject: Annotated[str, typer.Argument(help="A subject id (`simgen status` lists them).")]
) -> None:
    """A subject's stimulation sites: site index (what `regenerate` and `export-vtk` take), node id (what
    `simulate`, `learner personalize` and `learner predict` take) and position in mm."""
    from shared.reader import read_mesh, read_sites, subject_attrs

    try:
        mesh_id = subject_attrs(store, subject)["mesh_id"]
        nodes, mesh = read_sites(store, mesh_id), read_mesh(store, mesh_id)
    except (InputError, KeyError) as exc:
        _fail(InputError(f"cannot read the sites of subject {subject!r}: {exc}"))
    table = Table("site index", "node id", "x (mm)", "y (mm)", "z (mm)", title=f"{subject} (mesh {mesh_id})")
    for index, node in enumerate(nodes):
        table.add_row(str(index), str(node), *(f"{c:.2f}" for c in mesh.points[node]))
    console.print(table)


@app.command()
def unlock(
    store: StoreArg,
    force: Annotated[bool, typer.Option(help="Also remove a lock of another host (check its build is gone).")] = False,
) -> None:
    """Remove the lock of STORE left by a build that is gone (refused while a build of STORE runs on this host)."""
    from simgen.store.lock import unlock as run_unlock

    try:
        holder = run_unlock(store, force=force)
    except (InputError, OSError) as exc:
        _fail(exc, store)
    if holder is None:
        console.print(f"{store}: not locked")
    else:
        console.print(f"{store}: removed the lock of host {holder.get('host')}, pid {holder.get('pid')}")


@app.command()
def verify(
    store: StoreArg,
    sample: Annotated[
        int,
        typer.Option(
            min=0,
            max=1_000_000,
            help="Chunks of every subject recomputed with numba and compared bit for bit (a store of the "
            "torch or auto backend: within the tolerance of docs/solver-backends.md).",
        ),
    ] = 1,
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="Seed of the chunk sample.")] = 0,
) -> None:
    """Check the structure against the recorded spec, every checksum and chunk, and recompute a sample."""
    from simgen.store.verify import verify_store

    try:
        report = verify_store(store, sample=sample, seed=seed)
    except InputError as exc:
        _fail(exc)
    for problem in report.problems:
        console.print(f"[red]problem:[/red] {problem}")
    console.print(
        f"{store}: {report.chunks_checked} chunks read, {report.chunks_recomputed} recomputed, "
        f"{len(report.problems)} problem(s)"
    )
    if not report.ok:
        raise typer.Exit(code=1)


@app.command()
def card(
    store: StoreArg,
    out: Annotated[Path | None, typer.Option(help="Markdown file to write; printed when omitted.")] = None,
) -> None:
    """Write the Markdown dataset card of STORE: model, parameters, sizes, cost, statistics, provenance, citation."""
    from simgen.store.card import dataset_card

    try:
        if out is not None and not out.parent.exists():
            raise InputError(f"{out}: folder {out.parent} does not exist")
        text = dataset_card(store)
        if out is not None:
            out.write_text(text + "\n")
    except (InputError, OSError) as exc:
        _fail(exc, out)
    if out is None:
        typer.echo(text)
    else:
        console.print(f"dataset card of {store} -> {out}")


@app.command("export-vtk")
def export_vtk(
    store: StoreArg,
    subject: Annotated[str, typer.Argument(help="Subject id (see `simgen status`).")],
    site_index: Annotated[
        int, typer.Argument(min=0, help="Site index within the subject (0-based; `simgen sites` lists them).")
    ],
    out: Annotated[Path, typer.Option(help="Output folder for the .vtu frames and .pvd collection.")] = Path("vtk"),
) -> None:
    """Write one simulation as a ParaView time series (.pvd + one .vtu per frame)."""
    from simgen.store.export import export_vtk as run_export

    try:
        pvd = run_export(store, subject, site_index, out)
    except (InputError, OSError) as exc:
        _fail(exc, out)
    console.print(f"wrote {pvd} (open it in ParaView)")


if __name__ == "__main__":  # pragma: no cover
    app()
