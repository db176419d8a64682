"""The ``learner`` command line: thin wrappers around library functions."""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import numpy as np
import typer
from rich.console import Console

from shared.cli import MAX_SEED, SiteRegionOpt, SiteToleranceOpt, SiteXyzOpt, fail, finite, parse_ids, print_markdown
from shared.errors import InputError
from shared.sites import SITE_TOLERANCE

if TYPE_CHECKING:
    from learner.config import LearnerConfig

app = typer.Typer(
    help="learner: meta-learned personalised neural surrogates (metaPNS) of cardiac simulations.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()

SeedOpt = Annotated[int, typer.Option(min=0, max=MAX_SEED, help="Random seed.")]
DeviceOpt = Annotated[str, typer.Option(help="auto (CUDA where available), cpu, cuda or cuda:N.")]
RefineOpt = Annotated[
    int,
    typer.Option(
        min=0,
        max=10_000,
        help="Most gradient steps refining c on each context set (0: the encoder's mean); the count is chosen by "
        "leaving up to 3 recordings out in turn.",
    ),
]


def _fail(exc: Exception, path: str | Path | None = None) -> NoReturn:
    """Report bad input on one line and exit with code 2 (:func:`shared.cli.fail`)."""
    fail(console, exc, path)


def _draws(samples: int) -> int:
    """Check ``--samples``: a spread needs two draws or more."""
    if samples == 1:
        raise typer.BadParameter("one draw gives no spread; use 0 (mean only) or 2 or more")
    return samples


def _context_range(text: str) -> tuple[int, int]:
    """``'min,max'`` (or one size) as a range of context sizes, ``1 <= min <= max``."""
    try:
        sizes = [int(v) for v in text.split(",")]
    except ValueError:
        sizes = []
    if len(sizes) not in (1, 2) or not 1 <= sizes[0] <= sizes[-1]:
        raise InputError(f"--context: expected 'min,max' (or one size) with 1 <= min <= max, got {text!r}")
    return sizes[0], sizes[-1]


@app.command()
def train(
    config: Annotated[Path, typer.Argument(help="Training config (TOML).")],
    fresh: Annotated[bool, typer.Option(help="Start over instead of resuming from <out>/last.pt.")] = False,
    epochs: Annotated[int | None, typer.Option(min=1, max=100_000, help="Override train.epochs.")] = None,
    max_minutes: Annotated[
        float | None,
        typer.Option(
            min=0,
            callback=finite,
            help="Override train.max_minutes (0: none): no epoch starts that, with the validation closing the run, "
            "would end past it (the longest epoch and validation so far are the estimate).",
        ),
    ] = None,
    seed: Annotated[int | None, typer.Option(min=0, max=MAX_SEED, help="Override train.seed.")] = None,
    store: Annotated[Path | None, typer.Option(help="Override data.store.")] = None,
    out: Annotated[Path | None, typer.Option(help="Override the run directory.")] = None,
    kind: Annotated[str | None, typer.Option(help="Override model.kind (metapns or pns).")] = None,
    device: Annotated[str | None, typer.Option(help="Override train.device: auto, cpu, cuda or cuda:N.")] = None,
    nproc: Annotated[
        int,
        typer.Option(min=1, max=1024, help="Training processes on this host (DistributedDataParallel, as torchrun)."),
    ] = 1,
) -> None:
    """Meta-train a metaPNS (or PNS) model; resumes an interrupted run exactly.

    Under ``torchrun --nproc-per-node N -m learner train CFG`` every rank runs
    this command; rank 0 prints and writes the checkpoints and logs.
    """
    import os

    from learner.config import load_config
    from shared.reader import check_store

    try:
        cfg = _overridden(
            load_config(config),
            epochs=epochs,
            max_minutes=max_minutes,
            seed=seed,
            store=store,
            out=out,
            kind=kind,
            device=device,
        )
        check_store(cfg.data.store)  # a missing store fails before the run directory is made
        Path(cfg.out).mkdir(parents=True, exist_ok=True)  # an unusable run directory fails before torch loads
    except (InputError, OSError) as exc:
        _fail(exc, config)
    from learner.train.launcher import RankFailed, launch
    from learner.train.trainer import TrainingDiverged
    from learner.train.trainer import train as run

    main = os.environ.get("RANK", "0") == "0"
    if main:
        console.print(f"training {cfg.model.kind} on {cfg.data.store} -> {cfg.out}")
    try:
        if nproc > 1:
            result = launch(cfg, nproc, fresh=fresh, on_epoch=_show_epoch)
        else:
            result = run(cfg, fresh=fresh, progress=main, on_epoch=_show_epoch)
    except (InputError, TrainingDiverged, RankFailed, OSError) as exc:
        _fail(exc, cfg.out)
    note = " (time budget reached)" if result.stopped_early else ""
    if main:
        console.print(f"done: {result.epochs_done} epochs{note}; checkpoints in {result.out}")


def _overridden(
    cfg: LearnerConfig,
    epochs: int | None,
    max_minutes: float | None,
    seed: int | None,
    store: Path | None,
    out: Path | None,
    kind: str | None,
    device: str | None = None,
) -> LearnerConfig:
    """``cfg`` with the options that were given."""
    from dataclasses import replace

    from learner.config import config_from_mapping

    given = (("epochs", epochs), ("max_minutes", max_minutes), ("seed", seed), ("device", device))
    train = {k: v for k, v in given if v is not None}
    cfg = replace(cfg, train=replace(cfg.train, **train))
    if store is not None:
        cfg = replace(cfg, data=replace(cfg.data, store=str(store.resolve())))
    if out is not None:
        cfg = replace(cfg, out=str(out.resolve()))
    if kind is not None:
        cfg = config_from_mapping({**cfg.to_dict(), "model": {**cfg.to_dict()["model"], "kind": kind}})
    return cfg


def _show_epoch(row: dict) -> None:
    """One line per trained epoch."""
    val = f"  val target MSE {row['val_target_mse']:.4g}" if "val_target_mse" in row else ""
    console.print(
        f"epoch {row['epoch']:4d}  loss {row['total']:.4g}  target MSE {row['target_mse']:.4g}"
        f"  context MSE {row['context_mse']:.4g}  {row['seconds']:.1f} s{val}"
    )


@app.command()
def evaluate(
    checkpoint: Annotated[
        Path, typer.Argument(help="Model checkpoint (best.pt / last.pt) or a shipped model's name (`learner models`).")
    ],
    store: Annotated[Path, typer.Argument(help="Dataset store.")],
    out: Annotated[Path, typer.Option(help="Folder for evaluation.json / evaluation.md.")] = Path("report/eval"),
    subjects: Annotated[
        str, typer.Option(help="A split name (test, validation, train) or comma-separated ids.")
    ] = "test",
    context: Annotated[str, typer.Option(help="Context size range 'min,max' (or one size).")] = "1,5",
    sets: Annotated[int, typer.Option(min=1, max=10_000, help="Context sets per subject.")] = 3,
    max_targets: Annotated[int, typer.Option(min=0, max=1_000_000, help="Targets per context set (0 = all).")] = 40,
    observe: Annotated[
        str | None,
        typer.Option(
            help="Observed node set (default: the training one, the first of a mixture), or 'ecg': each context "
            "set as the 12-lead ECGs of its simulations (a model with an ECG encoder; --noise: a share of the "
            "largest lead value)."
        ),
    ] = None,
    noise: Annotated[
        float | None, typer.Option(min=0, callback=finite, help="Observation noise std (default: the training noise).")
    ] = None,
    seed: SeedOpt = 0,
    refine_steps: RefineOpt = 0,
    ensemble: Annotated[
        list[Path] | None,
        typer.Option(
            help="Another checkpoint (or shipped model) to average with CHECKPOINT's predictions (repeat for more)."
        ),
    ] = None,
    device: DeviceOpt = "auto",
) -> None:
    """Context and target MSE / CC / DC / activation-time error, per subject and overall."""
    from learner.evaluate import EvalSpec
    from learner.evaluate import evaluate as run
    from learner.refine import Refinement

    try:
        split = (
            subjects
            if "," not in subjects and subjects in ("test", "validation", "train")
            else tuple(subjects.split(","))
        )
        spec = EvalSpec(
            subjects=split,
            context=_context_range(context),
            context_sets=sets,
            max_targets=max_targets,
            observe=observe,
            noise_std=noise,
            seed=seed,
            refine=Refinement(steps=refine_steps),
        )
        checkpoints = [checkpoint, *(ensemble or [])]
        report = run(checkpoints, store, spec, lambda i, n, s: console.print(f"[{i}/{n}] {s}"), device)
    except (InputError, ValueError) as exc:
        _fail(exc)
    try:
        js, md = report.write(out)
    except OSError as exc:
        _fail(exc, out)
    print_markdown(console, report.to_markdown().split("### per subject")[0])
    console.print(f"wrote {js} and {md}")


def _training_log(run: Path) -> list[dict]:
    """The rows of ``run/log.jsonl``; a missing log or a line that is not JSON is bad input."""
    import json

    log = run / "log.jsonl"
    if not log.is_file():
        raise InputError(f"{log} not found: is {run} a training run directory?")
    rows = []
    for number, line in enumerate(log.read_text().splitlines(), 1):
        try:
            rows.extend([json.loads(line)] if line.strip() else [])
        except json.JSONDecodeError as exc:
            raise InputError(f"{log}: line {number} is not JSON ({exc.msg})") from None
    return rows


@app.command()
def curves(
    runs: Annotated[list[Path], typer.Argument(help="Run directories (each with a log.jsonl).")],
    out: Annotated[Path, typer.Option(help="PNG to write.")] = Path("report/training_curves.png"),
) -> None:
    """Plot the validation and training target MSE of one or more training runs against epoch."""
    from learner.plot import plot_training_curves

    try:
        logs = {run.name: _training_log(run) for run in runs}
    except (InputError, OSError) as exc:
        _fail(exc)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        console.print(f"wrote {plot_training_curves(logs, out)}")
    except OSError as exc:
        _fail(exc, out)


@app.command()
def personalize(
    checkpoint: Annotated[
        Path, typer.Argument(help="metaPNS checkpoint or a shipped model's name (`learner models`), e.g. anatomies.")
    ],
    out: Annotated[Path, typer.Option(help="Personalised surrogate file to write.")],
    store: Annotated[Path | None, typer.Option(help="Store holding the subject's simulations.")] = None,
    subject: Annotated[str | None, typer.Option(help="Subject id in --store.")] = None,
    sites: Annotated[str, typer.Option(help="Comma-separated stimulation node ids of the context set.")] = "",
    site_xyz: Annotated[
        str | None,
        typer.Option(
            "--site-xyz",
            help="Context sites of --store as points x,y,z in mm, ';' between points: each the subject's simulated "
            "site nearest it, within --site-tolerance.",
        ),
    ] = None,
    observe: Annotated[str, typer.Option(help="Observed node set (surface, epicardium, electrodes, ...).")] = "surface",
    observations: Annotated[
        Path | None,
        typer.Option(
            help=".npz (instead of --store): obs (K, T, N) float u = (V + 80) / 100, V in mV; sites (K,) int node ids "
            "or site_xyz (K, 3) mm; observed (N,) bool; times (T,) float in time units of 12.9 ms (the shipped "
            "model: T = 55, 0.6, 1.2, ..., 33.0); the mesh's points (N, 3) float mm and cells (M, 4|3) int; or "
            "activation_ms (K, N), or ecg_mv (K, 12, T) 12-lead ECGs with ecg_times_ms "
            "(docs/formats.md, examples/observations.npz)."
        ),
    ] = None,
    mesh: Annotated[
        Path | None,
        typer.Option(
            help="Mesh file (any meshio format, any resolution, read as it is: node ids are the file's) of "
            "--observations, which may then omit points and cells."
        ),
    ] = None,
    site_tolerance: SiteToleranceOpt = SITE_TOLERANCE,
    refine_steps: RefineOpt = 0,
    device: DeviceOpt = "auto",
) -> None:
    """Embed a subject's few observations into a saved personalised surrogate."""
    from learner.observations import observations_from_file, observations_from_store, read_mesh_file
    from learner.personalized import NoWaveWarning
    from learner.personalized import personalize as run
    from learner.refine import Refinement
    from shared.sites import parse_points

    try:
        if mesh is not None and observations is None:
            raise InputError("--mesh is the mesh of --observations: give --observations FILE too")
        if observations is not None:
            given = read_mesh_file(mesh) if mesh is not None else (None, None)
            obs = observations_from_file(observations, *given, tolerance=site_tolerance)
        elif store is not None and subject is not None:
            points = parse_points(site_xyz) if site_xyz is not None else None
            ids = parse_ids(sites, "--sites") if sites else []
            obs = observations_from_store(store, subject, ids, observe, points, site_tolerance)
        else:
            raise InputError("give either --observations FILE or --store, --subject and --sites (or --site-xyz)")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", NoWaveWarning)
            heart = run(checkpoint, obs, out, device, Refinement(steps=refine_steps))
    except (InputError, OSError) as exc:
        _fail(exc, out)
    for warning in caught:
        if issubclass(warning.category, NoWaveWarning):
            console.print(f"[yellow]{warning.message}[/yellow]", soft_wrap=True)
    history = heart.refine_objective
    refined = ""
    if refine_steps:
        refined = (
            f", refined in {heart.refine_steps_taken} of up to {refine_steps} steps (objective {history[0]:.4g} -> "
            f"{history[-1]:.4g}, the count chosen on held-out recordings)"
            if history
            else ", not refined (no step improved the held-out recordings, or a single recording)"
        )
    console.print(
        f"personalised on {len(obs.sites) - len(heart.dropped)} recording(s) in {1000 * heart.embed_seconds:.1f} ms"
        f"{refined}; {heart.graph_summary()} -> {out}",
        soft_wrap=True,
    )


@app.command()
def predict(
    personalized: Annotated[Path, typer.Argument(help="Personalised surrogate (from `learner personalize`).")],
    sites: Annotated[str | None, typer.Option(help="Comma-separated stimulation node ids.")] = None,
    site_xyz: SiteXyzOpt = None,
    site_region: SiteRegionOpt = None,
    site_tolerance: SiteToleranceOpt = SITE_TOLERANCE,
    out: Annotated[
        Path,
        typer.Option(
            help=".npz: sites, times_ms, v_mv (site, time, node) in mV, activation_ms, activated_fraction, "
            "started_wave, the mesh (points, cells) and, with --samples, spread_mv and activation_spread_ms."
        ),
    ] = Path("prediction.npz"),
    vtk: Annotated[
        Path | None, typer.Option(help="Folder for a ParaView time series per site (site-<node>.pvd).")
    ] = None,
    png: Annotated[
        Path | None, typer.Option(help="PNG of the predicted activation maps (and their spread), one row per site.")
    ] = None,
    samples: Annotated[
        int,
        typer.Option(
            min=0,
            max=10_000,
            callback=_draws,
            help="Draws of c for a predictive spread: 0 (mean only) or 2-10000; each costs one prediction's time "
            "(printed before they start), the memory stays that of three.",
        ),
    ] = 0,
    tissue: Annotated[
        Path | None,
        typer.Option(help="Also write the heart's tissue estimate (.npz, as `learner tissue --out`) to this file."),
    ] = None,
    device: DeviceOpt = "auto",
) -> None:
    """Predict full-mesh sequences for new stimulation sites (node ids, points or regions)."""
    from learner.personalized import PersonalizedHeart, plot_prediction, write_vtk
    from learner.runtime import peak_memory_mb
    from shared.sites import parse_points, parse_regions

    start = time.perf_counter()
    try:
        if sites is None and site_xyz is None and site_region is None:
            raise InputError("give the sites: --sites node ids, --site-xyz points or --site-region regions")
        heart = PersonalizedHeart.load(personalized, device)
        ids = parse_ids(sites, "--sites") if sites is not None else []
        points = parse_points(site_xyz) if site_xyz is not None else None
        regions = parse_regions(site_region) if site_region is not None else []

        def on_estimate(seconds: float, mb: float) -> None:
            console.print(f"{samples} draws of c: about {seconds:.1f} s and {mb:.0f} MB", soft_wrap=True)

        pred = heart.predict(heart.sites(ids, points, regions, site_tolerance), samples, on_estimate=on_estimate)
        estimate = heart.tissue() if tissue is not None else None
    except InputError as exc:
        _fail(exc)
    if estimate is not None:
        _write_tissue(estimate, tissue)
    arrays = pred.arrays()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez(out, **arrays)
    except OSError as exc:
        _fail(exc, out)
    console.print(
        f"{len(pred.sites)} sequence(s) of {heart.mesh.n_nodes} nodes in {1000 * pred.seconds:.1f} ms "
        f"({time.perf_counter() - start:.2f} s with loading, peak memory {peak_memory_mb():.0f} MB) -> {out}",
        soft_wrap=True,
    )
    for site, share in zip(pred.sites[~pred.started_wave], pred.activated[~pred.started_wave]):
        console.print(
            f"[yellow]site {int(site)}: the model predicts no propagating wave[/yellow] ({100 * share:.1f}% of the "
            "nodes activate): it reads the site as scar core",
            soft_wrap=True,
        )
    if vtk is not None:
        try:
            paths = write_vtk(pred, vtk)
        except OSError as exc:
            _fail(exc, vtk)
        console.print(f"wrote {len(paths)} time series ({', '.join(p.name for p in paths)}) to {vtk}")
    if png is not None:
        try:
            png.parent.mkdir(parents=True, exist_ok=True)
            console.print(f"wrote {plot_prediction(pred, png)}")
        except (OSError, ValueError) as exc:
            _fail(exc, png)


def _write_tissue(estimate, out: Path) -> None:
    """Write a tissue estimate's arrays to ``out`` (.npz) and say what it holds."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez(out, **estimate.arrays())
    except OSError as exc:
        _fail(exc, out)
    console.print(f"{estimate.summary()} -> {out}", soft_wrap=True)


@app.command("tissue")
def tissue_command(
    personalized: Annotated[Path, typer.Argument(help="Personalised surrogate (from `learner personalize`).")],
    out: Annotated[
        Path,
        typer.Option(
            help=".npz: abnormal_probability, abnormal_spread and abnormal per node, cv_m_per_s, cv_spread_m_per_s, "
            "cv_draws_m_per_s and the mesh (points, cells)."
        ),
    ] = Path("tissue.npz"),
    vtk: Annotated[
        Path | None, typer.Option(help=".vtu of the mesh with abnormal_probability, abnormal_spread and abnormal.")
    ] = None,
    png: Annotated[Path | None, typer.Option(help="PNG of the abnormal-tissue probability and its spread.")] = None,
    samples: Annotated[int, typer.Option(min=2, max=10_000, help="Draws of c the estimate averages.")] = 32,
    seed: Annotated[int, typer.Option(min=0, max=MAX_SEED, help="Seed of the draws.")] = 0,
    device: DeviceOpt = "auto",
) -> None:
    """What a personalised heart infers about its tissue: where it is scarred and how fast it conducts (m/s)."""
    from learner.personalized import PersonalizedHeart
    from learner.tissue_estimate import plot_tissue_estimate, write_tissue_vtk

    try:
        estimate = PersonalizedHeart.load(personalized, device).tissue(samples, seed)
    except InputError as exc:
        _fail(exc)
    _write_tissue(estimate, out)
    for path, write in ((vtk, write_tissue_vtk), (png, plot_tissue_estimate)):
        if path is not None:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                console.print(f"wrote {write(estimate, path)}")
            except (OSError, ValueError) as exc:
                _fail(exc, path)


@app.command()
def compare(
    prediction: Annotated[Path, typer.Argument(help="Prediction file (`learner predict --out`).")],
    simulation: Annotated[Path, typer.Argument(help="Simulation file of the same heart (`simgen simulate`).")],
    png: Annotated[
        Path | None, typer.Option(help="PNG: simulated and predicted activation maps side by side, one scale.")
    ] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="JSON of the metrics per site and overall.")] = None,
) -> None:
    """Score a prediction against a simulation: MSE, spatial and temporal CC, DC, activation error (ms) per site."""
    from rich.table import Table

    from learner.compare import compare_files, plot_comparison

    try:
        result = compare_files(prediction, simulation)
    except InputError as exc:
        _fail(exc)
    columns = (("mse", "MSE", ".4f"), ("cc_spatial", "spatial CC", ".3f"), ("cc_temporal", "temporal CC", ".3f"))
    columns += (("dc", "DC", ".3f"), ("act_error_ms", "activation error (ms)", ".1f"))
    table = Table("site", *(title for _, title, _ in columns))
    for site, row in zip(result.sites, result.per_site):
        table.add_row(str(int(site)), *(format(row[key], fmt) for key, _, fmt in columns))
    table.add_row("mean", *(format(result.overall[key]["mean"], fmt) for key, _, fmt in columns), style="bold")
    console.print(table)
    try:
        for path, write in ((json_out, result.write_json), (png, lambda p: plot_comparison(result, p))):
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                console.print(f"wrote {write(path)}")
    except OSError as exc:
        _fail(exc)


@app.command()
def models() -> None:
    """List the shipped pretrained models: use a name wherever a command takes a checkpoint."""
    from rich.table import Table

    from learner import pretrained

    table = Table("name", "kind", "parameters", "trained on")
    for name in pretrained.names():
        try:
            shipped = pretrained.info(name)
        except InputError as exc:
            _fail(exc)
        table.add_row(name, shipped.config["kind"], f"{shipped.parameters:,}", shipped.summary)
    console.print(table)
    console.print(f"model cards: {pretrained.SHIPPED_DIR}/<name>/README.md")


@app.command()
def export(
    checkpoint: Annotated[Path, typer.Argument(help="Training checkpoint (best.pt / last.pt).")],
    folder: Annotated[Path, typer.Argument(help="Folder to write; its name is the model's name.")],
    summary: Annotated[str, typer.Option(help="One line: what the model was trained on.")],
    spec: Annotated[str, typer.Option(help="The training spec it came from, as recorded in config.json.")] = "",
    store_spec: Annotated[str, typer.Option(help="The build spec of its training store, as recorded.")] = "",
) -> None:
    """Write a checkpoint as a shipped-model folder: model.safetensors (weights only) and config.json."""
    from learner.pretrained import export as run

    try:
        out = run(checkpoint, folder, summary, spec, store_spec)
    except (InputError, OSError) as exc:
        _fail(exc, folder)
    console.print(f"wrote {out}/model.safetensors and {out}/config.json; write the model card {out}/README.md")


@app.command()
def benchmark(
    config: Annotated[Path, typer.Argument(help="Benchmark config (TOML): store, checkpoints, baselines, real data.")],
    device: DeviceOpt = "auto",
) -> None:
    """Table 1 (4 methods), Fig. 3, timings, activation maps, calibration and real-data emulation -> <out>/."""
    from learner.benchmark import load_benchmark_config, run_benchmark

    try:
        cfg = load_benchmark_config(config)
    except (InputError, OSError) as exc:
        _fail(exc, config)
    try:
        run_benchmark(cfg, progress=console.print, device=device)
    except (InputError, OSError) as exc:
        _fail(exc, cfg.out)
    print_markdown(console, (Path(cfg.out) / "benchmark.md").read_text())
    console.print(f"wrote {cfg.out}/benchmark.md, benchmark.json, table1.md, timing.md and figures")
