"""The demo job: a small sweep (geometries x tissue settings x sites) with activation-map figures.

``simgen demo`` runs it; later issues extend it to build -> train -> evaluate.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.progress import Progress

from shared.mesh import Mesh
from simgen.meshes.catalog import get_mesh
from simgen.observe.sock import farthest_point_sampling
from simgen.plot import plot_activation_maps, plot_tissue
from simgen.solver.cells.aliev_panfilov import MS_PER_TIME_UNIT
from simgen.solver.simulate import Simulator, SolverConfig
from simgen.tissue import default_settings, tissue_fields

__all__ = ["DemoRow", "spread_sites", "run_demo"]

DEMO_SETTINGS = ("healthy", "scar-anterior-mid", "scar-septal-basal", "scar-apex")


@dataclass(frozen=True)
class DemoRow:
    """One (mesh, tissue setting) of the demo sweep."""

    mesh: str
    setting: str
    scar_fraction: float
    sites: list[int]
    seconds: float
    total_activation_ms: list[float]
    figure: str


def spread_sites(mesh: Mesh, n: int) -> np.ndarray:
    """``n`` stimulation sites spread over the surface by farthest-point sampling."""
    surface = mesh.nodes("surface")
    return surface[farthest_point_sampling(mesh.points[surface], n)]


def run_demo(
    out: Path,
    geometries: tuple[str, ...] = ("lv", "biv"),
    n_nodes: int = 2000,
    settings: tuple[str, ...] = DEMO_SETTINGS,
    n_sites: int = 4,
    threads: int = 2,
    config: SolverConfig | None = None,
) -> list[DemoRow]:
    """Simulate every geometry x setting x site, write PNGs and ``summary.{md,json}`` to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    specs = {spec.name: spec for spec in default_settings()}
    rows: list[DemoRow] = []
    with Progress() as progress:
        task = progress.add_task("simulating", total=len(geometries) * len(settings))
        for geometry in geometries:
            mesh = get_mesh(geometry, n_nodes)
            sites = spread_sites(mesh, n_sites)
            for name in settings:
                fields = tissue_fields(mesh, specs[name])
                start = time.perf_counter()
                result = Simulator(mesh, fields, config).run(sites, threads=threads)
                seconds = time.perf_counter() - start
                act_ms = result.activation * MS_PER_TIME_UNIT
                figure = f"activation_{geometry}_{name}.png"
                titles = [f"{geometry} {name} site {s}" for s in sites]
                plot_activation_maps(mesh, act_ms, titles, out / figure, stim_nodes=sites)
                plot_tissue(mesh, fields.label, out / f"tissue_{geometry}_{name}.png", f"{geometry}: {name}")
                rows.append(
                    DemoRow(
                        mesh=f"{geometry} ({mesh.n_nodes} nodes, {mesh.cell_type})",
                        setting=name,
                        scar_fraction=float(np.mean(fields.label > 0)),
                        sites=[int(s) for s in sites],
                        seconds=seconds,
                        total_activation_ms=[float(np.nanmax(a)) for a in act_ms],
                        figure=figure,
                    )
                )
                progress.advance(task)
    _write_summary(out, rows)
    return rows


def _write_summary(out: Path, rows: list[DemoRow]) -> None:
    (out / "summary.json").write_text(json.dumps([row.__dict__ for row in rows], indent=2))
    lines = [
        "# simgen demo",
        "",
        "| mesh | setting | scar fraction | sites | solver time (s) | total activation time per site (ms) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        acts = ", ".join(f"{t:.0f}" for t in r.total_activation_ms)
        lines.append(f"| {r.mesh} | {r.setting} | {r.scar_fraction:.1%} | {len(r.sites)} | {r.seconds:.2f} | {acts} |")
    lines += ["", "Figures: " + ", ".join(f"[{r.figure}]({r.figure})" for r in rows), ""]
    (out / "summary.md").write_text("\n".join(lines))
