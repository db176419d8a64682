"""The ``simgen`` command line's app, console, shared options and its one way of refusing bad input."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console

from shared.cli import fail, finite, needs
from simgen.meshes.fibres import HELIX_ENDO, HELIX_EPI

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


def fail_input(exc: Exception, path: str | Path | None = None) -> NoReturn:
    """Report bad input on one line and exit with code 2 (:func:`shared.cli.fail`)."""
    fail(console, exc, path)


def mesh_options(
    fibres: bool, helix_endo: float | None, helix_epi: float | None, filler: str | None, nodes: int | None
) -> tuple[float, float]:
    """The helix angles of the rule-based fibres; options that would have no effect are refused by name."""
    needs("--helix-endo", helix_endo is not None, "--fibres", fibres)
    needs("--helix-epi", helix_epi is not None, "--fibres", fibres)
    needs("--filler", filler is not None, "--nodes", nodes is not None)
    return (HELIX_ENDO if helix_endo is None else helix_endo, HELIX_EPI if helix_epi is None else helix_epi)
