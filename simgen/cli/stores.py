"""``simgen status``, ``sites``, ``unlock``, ``verify``, ``card`` and ``export-vtk``: the commands that read a store
(or free its lock)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from shared.cli import MAX_SEED
from shared.errors import InputError
from simgen.cli.options import StoreArg, app, console, fail_input


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
        fail_input(exc)
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
        fail_input(InputError(f"cannot read the sites of subject {subject!r}: {exc}"))
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
        fail_input(exc, store)
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
        fail_input(exc)
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
        fail_input(exc, out)
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
        fail_input(exc, out)
    console.print(f"wrote {pvd} (open it in ParaView)")


if __name__ == "__main__":  # pragma: no cover
    app()
