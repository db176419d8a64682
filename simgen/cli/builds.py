"""``simgen build``, ``add-subject``, ``regenerate`` and ``repair``: the commands that compute a store's chunks,
with their plan and progress."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from shared.cli import needs, parse_ids
from shared.errors import InputError
from simgen.cli.options import (
    TISSUE_HELP,
    FillerOpt,
    GpusOpt,
    KindOpt,
    NodesOpt,
    SchedulerOpt,
    StoreArg,
    UnitsOpt,
    WorkersOpt,
    app,
    console,
    fail_input,
)
from simgen.tissue import named_setting

if TYPE_CHECKING:
    from simgen.store.estimate import BuildEstimate


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
            fail_input(exc, store)
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
        fail_input(exc, store)
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
        fail_input(exc)
    if dry_run:
        try:
            lines = plan_repair(store, spec, rescope, remove_extra).lines()
        except InputError as exc:
            fail_input(exc)
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
