"""Benchmark: dataset builds on Dask into Zarr - 1 vs 2 workers, Zarr write share, paper scale.

Three measurements, each printed as a Markdown table:

1. **Scaling.** One small spec built in code (default: 1 LV mesh of ~2000
   nodes x 4 tissue settings x 192 sites, 64 sites per chunk = 12 tasks) is
   built into a fresh temporary store by :func:`simgen.store.runner.build`
   (LocalCluster of single-threaded worker processes) with 1 and with 2
   workers. Reported: build wall time and sims/s, the LocalCluster start-up
   alone (``dask_client`` entered and left with no work), the task phase
   (first submit to last completion, from the ``on_start``/``on_done`` hooks)
   and the workers' busy share over it (Dask task stream). The ratio it exists
   to show is the 2-vs-1 speed-up (goal >= 1.8x), on the whole build and on
   the task phase.
   A no-Dask ceiling runs the same chunks in 1 and 2 plain processes started
   together, to separate what the machine allows from what Dask costs.
2. **Zarr write share.** Without Dask, in this process: for each output
   setting (:data:`WRITE_CONFIGS`: none, blosc 3 and 1, zstd 1 at 64 sites
   per chunk; none at 32 and 128) a fresh store layout is created and the
   worker's steps are run by hand for every chunk of one subject (default 768
   sites: 12 chunks of 64 in a row, so that file writes are measured
   sustained, as in a build, not only the first few) -
   ``Simulator.run(sites, threads=1)`` then
   :func:`simgen.store.layout.write_chunk`, once in the task and once on a
   :class:`~simgen.store.worker.BackgroundWriter` as a build runs it - timing
   each part. Reported: the write share of task time (goal <= 5%), bytes
   written (u + activation chunks on disk) and the compression ratio
   (stored / raw float32 bytes).

Other processes on the machine skew every figure: the header reports the
CPUs they took during each measurement (``/proc/stat`` minus this process
tree) and warns above 0.1.
3. **Paper scale** (``--paper``, not run by default): ``specs/default.toml``
   (3 meshes x 16 settings x 200 sites = 9,600 simulations) built once per
   ``--paper-workers`` count (default 2; ``--paper-workers 1 2`` gives the
   2-vs-1 speed-up at full size) and ``--paper-repeat`` round (the counts
   alternating, fastest kept); wall time, sims/s and store size on disk
   (goal <= 15 min on 2 cores).

Run: ``.venv/bin/python -m bench.build [--paper [--paper-workers 1 2] [--paper-repeat 3]] [--out DIR]``
(DIR gets build.md and build.json). ``--publish`` writes the tables (without the summary lines)
into the block ``build`` of docs/results.md with the command and the machine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import distributed
import numpy as np
import zarr

from bench.common import (
    add_out_argument,
    add_publish_argument,
    check_publish,
    machine,
    machine_line,
    publish_out,
    write_out,
)
from simgen.store.layout import create_layout, write_chunk
from simgen.store.manifest import make_plan
from simgen.store.runner import build, dask_client
from simgen.store.spec import BuildSpec, load_spec, spec_from_mapping, spec_hash, spec_to_dict
from simgen.store.worker import BackgroundWriter, Prepared, prepare
from simgen.tissue.defaults import default_settings

ROOT = Path(__file__).resolve().parents[1]
PAPER_SPEC = ROOT / "specs" / "default.toml"
TISSUE = ["healthy", "scar-anterior-basal", "scar-septal-mid", "scar-lateral-apical"]
#: (compressor, level, chunk_sites) of the write-share table; the first is the default [output] setting,
#: which the summary line quotes.
WRITE_CONFIGS = [
    ("none", 0, 64),
    ("blosc", 3, 64),
    ("blosc", 1, 64),
    ("zstd", 1, 64),
    ("none", 0, 32),
    ("none", 0, 128),
]


class CpuMeter:
    """CPU seconds used by other processes (not this one or its children) while the ``with`` body runs.

    Machine-wide busy time from ``/proc/stat`` minus this process tree's own
    (``getrusage``; children count once reaped, as Dask's worker processes are
    when the cluster closes). ``others_cores`` is the average number of CPUs
    taken by other work: anything well above 0 means the timings are slowed.
    """

    def _read(self) -> tuple[float, float, float]:
        import resource

        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
        hz = os.sysconf("SC_CLK_TCK")
        own = sum(
            getattr(resource.getrusage(who), f)
            for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
            for f in ("ru_utime", "ru_stime")
        )
        busy = (v[0] + v[1] + v[2] + v[5] + v[6]) / hz  # user nice system irq softirq
        return time.perf_counter(), busy, own

    def __enter__(self) -> CpuMeter:
        self.others_cores = None
        self.start = self._read() if os.path.exists("/proc/stat") else None
        return self

    def __exit__(self, *exc) -> None:
        if self.start is not None:
            t, busy, own = (b - a for a, b in zip(self.start, self._read()))
            self.others_cores = max(0.0, busy - own) / t


def small_spec(
    nodes: int, settings: int, sites: int, chunk: int, compressor: str | None = None, level: int | None = None
) -> BuildSpec:
    """One procedural LV under ``settings`` tissue settings (healthy first), built in code.

    ``compressor`` / ``level``: the ``[output]`` defaults unless given.
    """
    names = [s.name for s in default_settings()]
    tissue = [n for n in TISSUE if n in names] + [n for n in names if n not in TISSUE]
    output = {"chunk_sites": chunk, "compressor": compressor, "level": level}
    return spec_from_mapping(
        {
            "name": "bench-build",
            "seed": 0,
            "tissue": tissue[:settings],
            "meshes": [{"id": "lv", "source": "lv", "nodes": nodes}],
            "sites": {"count": sites},
            "output": {k: v for k, v in output.items() if v is not None},
        }
    )


def disk_bytes(path: Path) -> tuple[int, int, int]:
    """(apparent bytes, allocated bytes as du counts them, file count) of everything under ``path``."""
    apparent = allocated = files = 0
    for root, _, names in os.walk(path):
        for name in names:
            st = os.lstat(os.path.join(root, name))
            apparent += st.st_size
            allocated += st.st_blocks * 512
            files += 1
    return apparent, allocated, files


def raw_bytes(spec: BuildSpec, plan) -> int:
    """float32 bytes of every subject's u and activation arrays."""
    frames = spec.solver.frames
    return sum(len(plan.sites[s.mesh_id]) * plan.meshes[s.mesh_id].n_nodes * (frames + 1) * 4 for s in plan.subjects)


def timed_build(spec: BuildSpec, store: Path, workers: int, progress: bool = False) -> dict:
    """``build(spec, store, workers=workers)`` with its phases timed and the task stream collected."""
    marks: dict = {"done": 0}

    def on_start(n_tasks: int, dashboard: str | None) -> None:
        marks["start"] = time.perf_counter()
        marks["n_tasks"] = n_tasks
        client = distributed.default_client()
        client.get_task_stream()  # make the scheduler record the task stream from now on
        marks["client"] = client

    def on_done(key: str) -> None:
        marks["done"] += 1
        marks["last"] = time.perf_counter()
        if marks["done"] == marks["n_tasks"]:  # still inside dask_client: fetch the stream before it closes
            marks["stream"] = marks["client"].get_task_stream()
        if progress and (marks["done"] % 24 == 0 or marks["done"] == marks["n_tasks"]):
            el = marks["last"] - marks["t0"]
            print(f"  {marks['done']}/{marks['n_tasks']} tasks, {el:.0f} s", file=sys.stderr, flush=True)

    marks["t0"] = t0 = time.perf_counter()
    report = build(spec, store, workers=workers, on_start=on_start, on_done=on_done)
    wall = time.perf_counter() - t0
    compute = [
        ss["stop"] - ss["start"]
        for rec in marks.get("stream", [])
        if str(rec.get("key", "")).startswith("simgen-")
        for ss in rec.get("startstops", ())
        if ss.get("action") == "compute"
    ]
    tasks_s = marks["last"] - marks["start"]
    return {
        "workers": workers,
        "tasks": report.tasks_run,
        "simulations": report.simulations,
        "wall_s": wall,
        "sims_per_s": report.simulations / wall,
        "before_tasks_s": marks["start"] - t0,
        "tasks_s": tasks_s,
        "after_tasks_s": t0 + wall - marks["last"],
        "task_sims_per_s": report.simulations / tasks_s,
        "task_compute_mean_s": float(np.mean(compute)) if compute else None,
        "busy": sum(compute) / (workers * tasks_s) if compute else None,
    }


def cluster_startup(workers: int) -> tuple[float, float]:
    """Seconds to enter (LocalCluster up, workers connected) and to leave ``dask_client`` with no work."""
    t0 = time.perf_counter()
    with dask_client(None, workers) as client:
        client.wait_for_workers(workers)
        t1 = time.perf_counter()
    return t1 - t0, time.perf_counter() - t1


def _solo(barrier, queue, nodes: int, sites: int, chunk: int) -> None:
    """Child process of :func:`bench_ceiling`: simulate ``sites`` sites chunk by chunk, no Dask, no writes."""
    from simgen.meshes.ellipsoid import lv_ellipsoid
    from simgen.solver.simulate import Simulator

    mesh = lv_ellipsoid(nodes, "tetra")
    sim = Simulator(mesh)
    nodes_ = np.random.default_rng(0).choice(mesh.n_nodes, size=sites, replace=False)
    sim.run(nodes_[:1], threads=1)  # JIT load, untimed
    barrier.wait()
    t0 = time.perf_counter()
    for start in range(0, sites, chunk):
        sim.run(nodes_[start : start + chunk], threads=1)
    queue.put(time.perf_counter() - t0)


def bench_ceiling(args) -> list[dict]:
    """The same chunks in P plain processes started together (no Dask): the machine's own scaling."""
    import multiprocessing as mp

    from simgen.store.runner import single_thread_env

    ctx = mp.get_context("spawn")
    rows = []
    with single_thread_env():
        for n_proc in args.workers:
            times = None
            for _ in range(args.repeat):  # fastest of `repeat` rounds
                barrier, queue = ctx.Barrier(n_proc), ctx.Queue()
                procs = [
                    ctx.Process(target=_solo, args=(barrier, queue, args.nodes, args.ceiling_sites, args.chunk))
                    for _ in range(n_proc)
                ]
                for proc in procs:
                    proc.start()
                got = [queue.get() for _ in procs]
                for proc in procs:
                    proc.join()
                if times is None or max(got) < max(times):
                    times = got
            chunks = -(-args.ceiling_sites // args.chunk)
            rows.append(
                {
                    "processes": n_proc,
                    "sims": n_proc * args.ceiling_sites,
                    "wall_s": max(times),
                    "chunk_s": float(np.mean(times)) / chunks,
                    "sims_per_s": n_proc * args.ceiling_sites / max(times),
                }
            )
    for row in rows:
        row["speedup"] = row["sims_per_s"] / rows[0]["sims_per_s"]
    return rows


def bench_scaling(args, tmp: Path) -> list[dict]:
    spec = small_spec(args.nodes, args.settings, args.sites, args.chunk)
    rows = []
    for w in args.workers:
        up, down = cluster_startup(w)
        t0 = time.perf_counter()
        plan = make_plan(spec)
        create_layout(tmp / f"layout-{w}.zarr", plan, spec_to_dict(spec), spec_hash(spec))
        layout_s = time.perf_counter() - t0
        shutil.rmtree(tmp / f"layout-{w}.zarr")
        best = None
        for r in range(args.repeat):
            row = timed_build(spec, tmp / f"scale-{w}-{r}.zarr", w)
            shutil.rmtree(tmp / f"scale-{w}-{r}.zarr")
            if best is None or row["wall_s"] < best["wall_s"]:
                best = row
        best.update(cluster_up_s=up, cluster_down_s=down, plan_layout_s=layout_s)
        rows.append(best)
    base = rows[0]
    for row in rows:
        row["speedup"] = base["wall_s"] / row["wall_s"]
        row["task_speedup"] = base["tasks_s"] / row["tasks_s"]
    return rows


def _worker_steps(store: Path, subject: str, prepared: Prepared, chunk: int, background: bool) -> dict:
    """``run_task`` by hand for every chunk of ``subject``, the writes in the task or on a :class:`BackgroundWriter`.

    Seconds: ``run`` in ``Simulator.run``; ``blocked`` the task thread waiting
    for writes (the whole ``write_chunk`` when in the task, else the wait for the
    previous write); ``flush`` the wait for the last write (once per worker and
    build); ``write_cpu`` CPU time of the writes on any thread (the process's CPU
    time less the simulations').
    """
    sim, sites, arrays = prepared
    writer = BackgroundWriter()
    run = blocked = sim_cpu = 0.0
    cpu0 = time.process_time()
    for c in range(-(-len(sites) // chunk)):
        start, stop = c * chunk, min((c + 1) * chunk, len(sites))
        t0, c0 = time.perf_counter(), time.thread_time()
        res = sim.run(sites[start:stop], threads=1)
        t1, c1 = time.perf_counter(), time.thread_time()
        args = store, subject, c, start, stop, res.u, res.activation, arrays
        if background:
            writer.submit(f"{subject}/{c}", write_chunk, *args)
        else:
            write_chunk(*args)
        run, blocked, sim_cpu = run + t1 - t0, blocked + time.perf_counter() - t1, sim_cpu + c1 - c0
    t0 = time.perf_counter()
    if writer.flush():
        raise RuntimeError("a background chunk write failed")
    flush = time.perf_counter() - t0
    return {"run": run, "blocked": blocked, "flush": flush, "write_cpu": time.process_time() - cpu0 - sim_cpu}


def bench_write(args, tmp: Path) -> list[dict]:
    """Worker steps by hand for every chunk of the first subject, per output setting, into fresh stores.

    Each setting runs with the writes in the task (as before :class:`BackgroundWriter`)
    and in the background (as a build's tasks do), alternately, fastest of ``repeat``.
    """
    rows = []
    for i, (compressor, level, chunk) in enumerate([WRITE_CONFIGS[0], *WRITE_CONFIGS]):  # the first is a warm-up
        spec = small_spec(args.nodes, 1, args.write_sites, chunk, compressor, level)
        plan = make_plan(spec)
        store = tmp / f"write-{i}.zarr"
        subject = plan.subjects[0].id
        best = {}
        for _ in range(1 if i == 0 else args.repeat):
            for mode in ("task", "background"):
                create_layout(store, plan, spec_to_dict(spec), spec_hash(spec))
                if not best:
                    t0 = time.perf_counter()
                    prepared = prepare(str(store), subject, spec.solver)  # once per subject and process, as a worker
                    sim, sites = prepared.sim, prepared.sites
                    setup_s = time.perf_counter() - t0
                    sim.run(sites[:1], threads=1)  # JIT load / warm-up, untimed
                r = _worker_steps(store, subject, prepared, chunk, background=mode == "background")
                r["cost"] = r["blocked"] + (r["write_cpu"] if mode == "background" else 0.0)
                r["share"] = r["cost"] / (r["run"] + r["cost"])
                if mode not in best or r["share"] < best[mode]["share"]:
                    best[mode] = r
                g = store / "subjects" / subject
                stored = sum(disk_bytes(g / name)[0] for name in ("u", "activation"))
                shutil.rmtree(store)
        raw = raw_bytes(spec, plan)
        n_chunks = -(-len(sites) // chunk)
        task, bg = best["task"], best["background"]
        rows.append(
            {
                "compressor": compressor if compressor == "none" else f"{compressor} {level}",
                "chunk_sites": chunk,
                "chunks": n_chunks,
                "sites": len(sites),
                "setup_s": setup_s,
                "run_s": bg["run"],
                "write_s": task["blocked"],
                "task_write_share": task["share"],
                "task_write_cpu_s": task["write_cpu"],
                "write_ms_per_chunk": 1e3 * task["blocked"] / n_chunks,
                "blocked_s": bg["blocked"],
                "flush_s": bg["flush"],
                "write_cpu_s": bg["write_cpu"],
                "write_cpu_ms_per_chunk": 1e3 * bg["write_cpu"] / n_chunks,
                "write_share": bg["share"],
                "stored_bytes": stored,
                "raw_bytes": raw,
                "ratio": stored / raw,
            }
        )
    return rows[1:]


def bench_paper(args, tmp: Path) -> list[dict]:
    """The paper-scale spec built once per ``--paper-workers`` count and round, each into a fresh store.

    Rounds alternate the worker counts (1, 2, 1, 2, ...), so that a slow spell of
    the host falls on both; the fastest build per count is kept, with every
    round's speed-ups over the first count (``round_speedups``).
    """
    spec = load_spec(args.paper_spec)
    raw = raw_bytes(spec, make_plan(spec))
    runs: dict[int, list[dict]] = {w: [] for w in args.paper_workers}
    for r in range(args.paper_repeat):
        for i, workers in enumerate(args.paper_workers):
            last = r == args.paper_repeat - 1 and i == len(args.paper_workers) - 1
            keep = args.paper_store is not None and last  # --paper-store: the last build
            store = args.paper_store if keep else tmp / f"paper-{workers}-{r}.zarr"
            if store.exists():
                raise SystemExit(f"{store} exists; give a new --paper-store path")
            print(
                f"paper-scale build of {args.paper_spec} into {store} with {workers} workers "
                f"(round {r + 1} of {args.paper_repeat}) ...",
                file=sys.stderr,
                flush=True,
            )
            row = timed_build(spec, store, workers, progress=True)
            apparent, allocated, files = disk_bytes(store)
            subjects = len(zarr.open_group(str(store), mode="r")["subjects"])
            row.update(
                spec=str(args.paper_spec),
                store_bytes=apparent,
                store_du_bytes=allocated,
                store_files=files,
                raw_bytes=raw,
                ratio=apparent / raw,
                subjects=subjects,
            )
            if not keep:
                shutil.rmtree(store)
            runs[workers].append(row)
    base = runs[args.paper_workers[0]]
    rows = []
    for built in runs.values():
        row = min(built, key=lambda b: b["wall_s"])
        row["speedup"] = min(b["wall_s"] for b in base) / row["wall_s"]
        row["task_speedup"] = min(b["tasks_s"] for b in base) / min(b["tasks_s"] for b in built)
        row["round_speedups"] = [b0["wall_s"] / b["wall_s"] for b0, b in zip(base, built)]
        row["rounds"] = len(built)
        rows.append(row)
    return rows


def _f(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def _scaling_md(scaling: list[dict], ceiling: list[dict], args) -> list[str]:
    out = [
        f"#### Scaling: 1 LV mesh ({args.nodes} nodes) x {args.settings} tissue settings x {args.sites} sites, "
        f"{args.chunk} sites per chunk; fastest of {args.repeat}",
        "",
        "| workers | tasks | sims | cluster up / down (s) | plan + layout (s) | build wall (s) | sims/s "
        "| before tasks (s) | task phase (s) | after tasks (s) | task sims/s | mean task (s) | busy "
        "| speed-up (wall) | speed-up (tasks) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in scaling:
        out.append(
            f"| {r['workers']} | {r['tasks']} | {r['simulations']} | {r['cluster_up_s']:.2f} / "
            f"{r['cluster_down_s']:.2f} | {r['plan_layout_s']:.2f} | {r['wall_s']:.2f} | {r['sims_per_s']:.1f} "
            f"| {r['before_tasks_s']:.2f} | {r['tasks_s']:.2f} | {r['after_tasks_s']:.2f} "
            f"| {r['task_sims_per_s']:.1f} | {_f(r['task_compute_mean_s'], '.3f')} "
            f"| {_f(r['busy'] and 100 * r['busy'], '.0f')}% | {r['speedup']:.2f}x "
            f"| {r['task_speedup']:.2f}x |"
        )
    out += [
        "",
        "cluster up / down = `dask_client` entered and left alone, no work; before tasks = plan + layout + "
        "cluster start-up inside `build`; after tasks = cluster shut-down + consolidate; busy = worker compute "
        "time / (workers x task phase); mean task = worker compute time per task (Dask task stream).",
        "",
        f"No-Dask ceiling: {args.ceiling_sites} sites per process in chunks of {args.chunk}, P plain processes "
        f"started together (simulation only, no writes), fastest of {args.repeat}:",
        "",
        "| processes | sims | wall (s) | s per chunk | sims/s | speed-up |",
        "|---:|---:|---:|---:|---:|---:|",
        *[
            f"| {c['processes']} | {c['sims']} | {c['wall_s']:.2f} | {c['chunk_s']:.3f} | {c['sims_per_s']:.1f} "
            f"| {c['speedup']:.2f}x |"
            for c in ceiling
        ],
    ]
    return out


def _write_md(write: list[dict], args) -> list[str]:
    out = [
        f"#### Zarr write share: worker steps by hand, 1 subject x {args.write_sites} sites, threads=1, no Dask; "
        f"fastest of {args.repeat}",
        "",
        "| compressor | chunk_sites | chunks | Simulator.run (s) | in the task: write_chunk (s) | write ms/chunk "
        "| share | background: task blocked (s) | last write (s) | write CPU (s) | write CPU ms/chunk "
        "| **write share** | stored MB | raw MB | stored/raw |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in write:
        out.append(
            f"| {r['compressor']} | {r['chunk_sites']} | {r['chunks']} | {r['run_s']:.2f} | {r['write_s']:.3f} "
            f"| {r['write_ms_per_chunk']:.0f} | {100 * r['task_write_share']:.1f}% | {r['blocked_s']:.3f} "
            f"| {r['flush_s']:.3f} | {r['write_cpu_s']:.3f} | {r['write_cpu_ms_per_chunk']:.1f} "
            f"| **{100 * r['write_share']:.1f}%** "
            f"| {r['stored_bytes'] / 1e6:.1f} | {r['raw_bytes'] / 1e6:.1f} | {r['ratio']:.3f} |"
        )
    out += [
        "",
        "In the task: `write_chunk` after `Simulator.run`, share = write_chunk / (run + write_chunk). "
        "Background (what a build's tasks do, `simgen.store.worker.BackgroundWriter`): the chunk is written on "
        "a thread of its own while the next one simulates; write share = (task blocked + write CPU) / "
        "(run + task blocked + write CPU), the write CPU counted in full as if no core were spare (a 2-worker "
        "build on 2 cores); the disk wait it hides costs nothing. Last write = the wait for the last chunk's "
        "write, once per worker and build (the driver's flush), not in the share. Simulator assembly (once "
        f"per subject and process, {write[0]['setup_s']:.2f} s here) excluded; stored = u + activation chunk files; "
        "blosc = lz4 inside blosc with bitshuffle.",
    ]
    return out


def _paper_md(paper: list[dict]) -> list[str]:
    rounds = paper[0]["rounds"]
    out = [
        f"#### Paper scale: {Path(paper[0]['spec']).name}" + (f"; fastest of {rounds}" if rounds > 1 else ""),
        "",
        "| workers | subjects | tasks | sims | wall (s) | wall (min) | sims/s | before tasks (s) | task phase (s) "
        "| after tasks (s) | mean task (s) | busy | speed-up (wall) | speed-up (tasks) | store GB | raw GB "
        "| stored/raw | files |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for p in paper:
        out.append(
            f"| {p['workers']} | {p['subjects']} | {p['tasks']} | {p['simulations']} | {p['wall_s']:.0f} "
            f"| {p['wall_s'] / 60:.1f} | {p['sims_per_s']:.1f} | {p['before_tasks_s']:.1f} | {p['tasks_s']:.1f} "
            f"| {p['after_tasks_s']:.1f} | {_f(p['task_compute_mean_s'], '.3f')} "
            f"| {_f(p['busy'] and 100 * p['busy'], '.0f')}% | {p['speedup']:.2f}x | {p['task_speedup']:.2f}x "
            f"| {p['store_bytes'] / 1e9:.2f} | {p['raw_bytes'] / 1e9:.2f} | {p['ratio']:.3f} "
            f"| {p['store_files']} |"
        )
    out += [
        "",
        "store GB = apparent size of the files (du counts more while the file system still holds "
        "preallocated blocks); the first row is the speed-up base (task phase: fastest against fastest).",
    ]
    if rounds > 1:
        out.append(
            "Speed-up (wall) of each round, the worker counts built one after the other: "
            + "; ".join(
                f"{p['workers']} workers " + " / ".join(f"{x:.2f}x" for x in p["round_speedups"]) for p in paper[1:]
            )
            + "."
        )
    return out


def markdown(
    scaling: list[dict], ceiling: list[dict], write: list[dict], paper: list[dict], args, summary: bool = True
) -> str:
    """Summary against the goals (unless ``summary`` is false), then one table per measurement that ran."""
    goals = []
    if scaling:
        last = scaling[-1]
        goals.append(
            f"{last['workers']}-vs-{scaling[0]['workers']} workers speed-up {last['speedup']:.2f}x on the "
            f"build wall time, {last['task_speedup']:.2f}x on the task phase (goal >= 1.8x; no-Dask "
            f"ceiling {ceiling[-1]['speedup']:.2f}x)"
        )
    if write:
        goals.append(
            f"Zarr write share {100 * write[0]['write_share']:.1f}% at {write[0]['compressor']}, "
            f"chunk {write[0]['chunk_sites']} (goal <= 5%)"
        )
    for p in paper:
        goals.append(
            f"paper-scale build with {p['workers']} worker(s) {p['wall_s'] / 60:.1f} min, "
            f"{p['sims_per_s']:.1f} sims/s, {p['store_bytes'] / 1e9:.2f} GB of files (goal <= 15 min)"
            + (f", {p['speedup']:.2f}x the first (goal >= 1.8x)" if p is not paper[0] else "")
        )
    out = [f"- {g}" for g in goals] if summary else []
    for section in (
        _scaling_md(scaling, ceiling, args) if scaling else [],
        _write_md(write, args) if write else [],
        _paper_md(paper) if paper else [],
    ):
        if section:
            out += ["", *section]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, default=2000, help="nodes of the LV mesh (default 2000)")
    p.add_argument("--settings", type=int, default=4, help="tissue settings of the scaling spec (default 4)")
    p.add_argument("--sites", type=int, default=192, help="sites per subject of the scaling spec (default 192)")
    p.add_argument("--chunk", type=int, default=64, help="sites per chunk of the scaling spec (default 64)")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts; the first is the base")
    p.add_argument("--repeat", type=int, default=2, help="rounds per worker count, fastest kept (default 2)")
    p.add_argument("--ceiling-sites", type=int, default=192, help="sites per process of the no-Dask ceiling")
    p.add_argument("--write-sites", type=int, default=768, help="sites simulated per write-share row (default 768)")
    p.add_argument("--paper", action="store_true", help="also build the paper-scale spec (minutes)")
    p.add_argument("--paper-only", action="store_true", help="only the paper-scale build")
    p.add_argument("--paper-spec", type=Path, default=PAPER_SPEC, help="spec of --paper (default specs/default.toml)")
    p.add_argument(
        "--paper-workers",
        type=int,
        nargs="+",
        default=[2],
        help="worker counts of --paper, one build each; the first is the speed-up base (default 2)",
    )
    p.add_argument(
        "--paper-repeat",
        type=int,
        default=1,
        help="rounds of --paper builds, worker counts alternating; fastest kept (default 1)",
    )
    p.add_argument("--paper-store", type=Path, help="keep the last --paper store at this new path (default: temporary)")
    p.add_argument("--tmp", type=Path, help="parent folder of the temporary stores (default: system temp)")
    add_out_argument(p, "build")
    add_publish_argument(p, "build")
    args = p.parse_args(argv)
    check_publish(args.publish)

    load_before = os.getloadavg()[0]
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="simgen-bench-build-", dir=args.tmp) as tmp:
        others = {}
        sections = (
            []
            if args.paper_only
            else [
                ("scaling", lambda: bench_scaling(args, Path(tmp))),
                ("ceiling", lambda: bench_ceiling(args)),
                ("write", lambda: bench_write(args, Path(tmp))),
            ]
        )
        if args.paper or args.paper_only:
            sections.append(("paper", lambda: bench_paper(args, Path(tmp))))
        results = {}
        for name, run in sections:
            with CpuMeter() as meter:
                results[name] = run()
            others[name] = meter.others_cores
    scaling, ceiling, write = (results.get(k, []) for k in ("scaling", "ceiling", "write"))
    paper = results.get("paper", [])
    total = time.perf_counter() - t_start
    header = (
        f"Build bench: {machine_line()}, dask.distributed "
        f"{distributed.__version__}, zarr {zarr.__version__}; total {total:.0f} s; "
        f"1-min load average before the run {load_before:.1f}\n"
    )
    busy = {k: v for k, v in others.items() if v is not None}
    if busy:
        header += (
            "CPUs taken by other processes during each measurement (average): "
            + ", ".join(f"{k} {v:.2f}" for k, v in busy.items())
            + "\n"
        )
    if any(v > 0.1 for v in busy.values()) if busy else load_before > 0.5:
        header += "WARNING: other processes were using the CPUs; the 2-worker figures above all are slowed.\n"
    if os.cpu_count() and max(args.workers) >= os.cpu_count():
        header += (
            f"Note: {max(args.workers)} single-threaded workers on {os.cpu_count()} CPUs share them with the "
            "driver (scheduler, client) and the nanny processes.\n"
        )
    table = header + "\n" + markdown(scaling, ceiling, write, paper, args) + "\n"
    print(table)
    publish_out(args.publish, "build", header + "\n" + markdown(scaling, ceiling, write, paper, args, summary=False))
    meta = {
        **machine(),
        "distributed": distributed.__version__,
        "zarr": zarr.__version__,
        "total_s": total,
        "load_average_before": load_before,
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "others_cores": others,
        "scaling": scaling,
        "ceiling": ceiling,
        "write": write,
        "paper": paper,
    }
    write_out(args.out, "build", table, meta, indent=2)


if __name__ == "__main__":
    main()
